"""The character: mesh, skeleton and forward kinematics, weights, servo map, loaders."""
