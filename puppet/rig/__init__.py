"""The character: mesh, skeleton and forward kinematics, weights, servo map, loaders.

Entry points: :func:`builtin` (the shipped character) and :func:`load_rig` (a TOML rig file,
or a bare .glb/.gltf/.npz character). A :class:`Rig` gives the solver its constraint pattern
(:meth:`Rig.pattern`) and per-frame values (:meth:`Rig.fill_values`).
"""

from puppet.rig.calibration import Calibration
from puppet.rig.errors import RigError
from puppet.rig.load import builtin, load_rig
from puppet.fast.energy_names import ENERGIES
from puppet.rig.rig import Rig, SolverOptions
from puppet.rig.servo_map import Servo, ServoMap
from puppet.rig.skeleton import Joint, Skeleton
from puppet.rig.weight_check import WeightReport, check_weights

__all__ = ["Calibration", "ENERGIES", "Joint", "Rig", "RigError", "Servo", "ServoMap", "Skeleton",
           "SolverOptions", "WeightReport", "builtin", "check_weights", "load_rig"]
