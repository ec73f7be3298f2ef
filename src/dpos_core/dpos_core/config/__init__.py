"""Configuration of the installation and its sensors, shared by the simulator, the estimators and
the nodes: aircraft file (:mod:`.aircraft`), sensor models (:mod:`.sensors`), wing flexure model
(:mod:`.flexure`) and the built-in YAML files (:mod:`.files`).  Nothing here simulates.
"""

from .aircraft import AircraftConfig, AntennaConfig, SubImuConfig, load_aircraft, scenario_aircraft, scenario_aircraft_ref
from .files import ConfigError, builtin_names, config_text
from .flexure import K_BEND, FlexureModel
from .sensors import GnssModel, ImuErrorModel, NavNoiseModel, NoiseInterval

__all__ = ["AircraftConfig", "AntennaConfig", "SubImuConfig", "load_aircraft", "scenario_aircraft", "scenario_aircraft_ref", "ConfigError", "builtin_names", "config_text",
           "K_BEND", "FlexureModel", "GnssModel", "ImuErrorModel", "NavNoiseModel", "NoiseInterval"]
