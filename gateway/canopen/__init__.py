"""CANopen (spec 3.3): the object dictionary and EDS (``dictionary``) and the node (``node``).

With ``ncgate.gateway.testing.canopen_kit``, the only place that imports canopen or can.
"""
