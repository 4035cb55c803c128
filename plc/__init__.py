"""The soft PLC: the I/O image, the index of waits on it, the scan cycle.  Stdlib only."""
