"""Configuration: the schema, the TOML loader, the built-in default config and its programs.

Stdlib only; of the other packages it imports only the interpreter's leaf module of settings
(``ncgate.interpreter.settings``), whose choices (the SND policy) the config names.
"""

from ncgate.config.reader import load_config
from ncgate.config.schema import (
    CanopenConfig,
    Config,
    ConfigError,
    Evict,
    MasterLost,
    ModbusConfig,
    ModbusMapConfig,
    ModbusRtuConfig,
    ModbusRtuTcpConfig,
    ModbusTlsConfig,
    NcConfig,
    Parity,
    PlcConfig,
    ProcessConfig,
    StorageConfig,
    TraceConfig,
    WebConfig,
    WebTlsConfig,
    default_config_path,
    default_script_path,
)
from ncgate.interpreter.settings import SndPolicy

__all__ = [
    "CanopenConfig",
    "Config",
    "ConfigError",
    "Evict",
    "MasterLost",
    "ModbusConfig",
    "ModbusMapConfig",
    "ModbusRtuConfig",
    "ModbusRtuTcpConfig",
    "ModbusTlsConfig",
    "NcConfig",
    "Parity",
    "PlcConfig",
    "ProcessConfig",
    "SndPolicy",
    "StorageConfig",
    "TraceConfig",
    "WebConfig",
    "WebTlsConfig",
    "default_config_path",
    "default_script_path",
    "load_config",
]
