"""IEC 61131-3 Structured Text for the soft PLC: the parser, the compiler to a ``Logic`` the
scan runs (``compiler``), the standard function blocks and functions (``stdlib``), PLCopen
TC6 XML (``plcopen``) and the diagnostics (``diagnostics``)."""
