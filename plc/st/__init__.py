"""IEC 61131-3 Structured Text for the soft PLC (issue 12): so far the standard function
blocks and functions (``stdlib``); the compiler and the scan cycle build on them."""
