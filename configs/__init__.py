"""The shipped configs (YAML files beside this module). Installed as the package ``airimu_configs`` (pyproject maps
it to this folder), so that a non-editable install finds them: ``airimu_core.config.config_path("euroc.yaml")``."""

from pathlib import Path

FOLDER = Path(__file__).resolve().parent


def names() -> list[str]:
    """The file names of the shipped configs."""
    return sorted(p.name for p in FOLDER.glob("*.yaml"))
