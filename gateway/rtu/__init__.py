"""Modbus RTU: the same map as Modbus TCP, framed as Modbus over Serial Line V1.02 has it, on a
serial port (pyserial) and on a TCP listener (RTU over TCP, as serial device servers carry
it).  An adapter of the registry (``ncgate.gateway.adapters``): this folder and one line
there.  The frame format is the sans-IO ``RtuFramer`` of ``ncgate.gateway.modbus.framer``;
the requests are answered by the Modbus TCP server's ``RequestHandler``, through the same
door."""
