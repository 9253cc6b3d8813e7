"""Stage 3, verification of one step's straight path (`path.verify_step`).

Imports the contact stage (broad phase, CCD) and the base modules.
"""
