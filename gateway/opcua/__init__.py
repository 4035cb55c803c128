"""The OPC UA server (docs/opcua.md): the cell as an OPC 40501 machine tool with OPC 40502 CNC
channels, and the image under ``urn:ncgate:image``, for dashboards.  Only this folder imports
asyncua (tests/test_layering.py)."""
