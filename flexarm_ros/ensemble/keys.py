"""Scene key paths (``links[0].joint.drive.resistance``): moved to
:mod:`flexarm_ros.scene.keys` so that the commands below the ensemble (``flexarm
simulate --set``, the twin's nodes) use them without importing the ensemble; this module
keeps the old import path."""

from flexarm_ros.scene.keys import (KeyField, check_numeric, get_key, key_field,  # noqa: F401
                                    parse_path, put_keys, scene_mapping, set_keys)

__all__ = ["KeyField", "check_numeric", "get_key", "key_field", "parse_path", "put_keys",
           "scene_mapping", "set_keys"]
