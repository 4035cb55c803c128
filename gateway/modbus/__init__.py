"""Modbus TCP (spec 3.2): the map in force (``map``) and the server (``server``).

With ``ncgate.gateway.testing.modbus_kit``, the only place that imports pymodbus.
"""
