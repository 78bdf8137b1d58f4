"""puppet: a physical puppet of Dynamixel servos drives a skinned character.

Parts (see DESIGN.md): ``puppet.bus`` reads servos, ``puppet.rig`` holds the character and
its servo map, ``puppet.fast`` solves the FAST reduced ARAP energy, ``puppet.render`` draws
offscreen with moderngl, ``puppet.take`` records and replays, ``puppet.loop`` joins them.
"""

__version__ = "0.1.0"
