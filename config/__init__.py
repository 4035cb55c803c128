"""Configuration: the schema, the TOML loader, the built-in default config and its programs.

Stdlib only; imports nothing from the other packages.
"""

from ncgate.config.loader import (
    CanopenConfig,
    Config,
    ConfigError,
    ModbusConfig,
    ModbusMapConfig,
    NcConfig,
    PlcConfig,
    ProcessConfig,
    SndPolicy,
    StorageConfig,
    default_config_path,
    default_script_path,
    load_config,
)

__all__ = [
    "CanopenConfig",
    "Config",
    "ConfigError",
    "ModbusConfig",
    "ModbusMapConfig",
    "NcConfig",
    "PlcConfig",
    "ProcessConfig",
    "SndPolicy",
    "StorageConfig",
    "default_config_path",
    "default_script_path",
    "load_config",
]
