"""What users' own test suites use: the pytest plugin (``ncgate[pytest]``), the virtual-PLC
Modbus client (``modbus_kit``) and the CANopen master (``canopen_kit``)."""
