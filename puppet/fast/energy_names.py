"""The ARAP energy types the FAST precompute builds (``puppet.fast.energy``), by name, as data.

Kept apart from ``energy`` (which needs scipy) so a rig file is checked against this one list
without importing the solver's numerics. Edge sets (as libigl's ARAPEnergyType):

- ``spokes``:          one set per vertex: its incident edges.
- ``spokes_and_rims``: one set per vertex: every edge of every incident triangle.
- ``elements``:        one set per triangle or tet: its edges.
"""

ENERGIES = ("spokes", "spokes_and_rims", "elements")
