"""Data files of the built-in character (critter.npz, critter.toml) and the script that makes them."""
