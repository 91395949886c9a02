"""The toolkit's configuration machinery, numpy- and torch-free: YAML read with ``yaml.SafeLoader`` (a key given
twice refused), typed frozen dataclasses built from the mapping with every key and type checked (``from_dict``; an
unknown, missing or ill-typed key is a ``ConfigError`` naming the file and the key's dotted path), and the shipped
configs found by name (``config_path``). Noise conventions: ``*_noise_density`` is sigma (rad/s/sqrt(Hz),
m/s^2/sqrt(Hz)); ``*_cov`` is sigma^2."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path
from typing import Any, Literal

import yaml

from airimu_core.errors import ConfigError


def config_path(path: str | Path) -> Path:
    """``path``, or, where no such file exists and it names a shipped config (``euroc.yaml`` or
    ``configs/euroc.yaml``), the installed copy of that config (package ``airimu_configs``)."""
    path = Path(path)
    if path.exists() or path.parent not in (Path("."), Path("configs")):
        return path
    try:
        import airimu_configs
    except ImportError:  # a source tree that is not installed
        return path
    shipped = airimu_configs.FOLDER / path.name
    return shipped if shipped.is_file() else path


class UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` (plain data only, as ``yaml.safe_load``) that refuses a key given twice in one mapping:
    PyYAML keeps the last one without a word, so ``epochs: 3`` above a forgotten ``epochs: 30`` trained 30."""


def _unique_mapping(loader: UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict = {}
    for key_node, _ in node.value:
        key, line = loader.construct_object(key_node, deep=True), key_node.start_mark.line + 1
        try:
            repeated = key in seen
        except TypeError:  # an unhashable key: the base constructor refuses it with its own message
            continue
        if repeated:
            raise _RepeatedKey(
                f"key {key!r} given twice (lines {seen[key]} and {line}); YAML would keep the second "
                "without a word: remove one"
            )
        seen[key] = line
    return loader.construct_mapping(node, deep=deep)


class _RepeatedKey(yaml.YAMLError):
    pass


UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _unique_mapping)


def read_yaml(path: Path):
    """A config file as plain data (``UniqueKeyLoader``: ``yaml.safe_load``'s loader, a repeated key refused);
    unreadable files and YAML errors are ``ConfigError``s naming it."""
    try:
        return yaml.load(path.read_text(), Loader=UniqueKeyLoader)  # noqa: S506 (a SafeLoader subclass)
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the config: {error.strerror}") from error
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: not a text file in UTF-8 (byte {error.start}): a config is YAML text") from None
    except _RepeatedKey as error:
        raise ConfigError(f"{path}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"{path}: not valid YAML: {error}") from error


# Keys renamed by the naming rule (``*_cov``: a variance or continuous-time density, sigma^2, as GTSAM's setters take
# it; ``*_noise_density``: sigma, as Kalibr writes it): an old key is an error naming the new one.
RENAMED_KEYS = {
    "init_gyro_density": ("init_gyro_cov", "sigma^2, rad^2/s"),
    "init_acc_density": ("init_acc_cov", "sigma^2, m^2/s^3"),
    "fixed_gyro_density": ("fixed_gyro_noise_density", "sigma, rad/s/sqrt(Hz)"),
    "fixed_acc_density": ("fixed_acc_noise_density", "sigma, m/s^2/sqrt(Hz)"),
}


# Plausible IMU noise, orders of magnitude around every real sensor (navigation-grade gyros ~5e-7 rad/s/sqrt(Hz),
# consumer MEMS ~1e-2): a sigma outside these is a sigma^2 given as sigma (or the reverse), or another unit.
NOISE_DENSITY_RANGE = {"gyro": (1e-7, 1.0), "acc": (1e-6, 10.0)}  # sigma: rad/s/sqrt(Hz), m/s^2/sqrt(Hz)


def check_noise_density(sensor: str, sigma: float, where: str) -> None:
    """A ``ConfigError`` naming ``where`` if ``sigma`` (a ``*_noise_density``) is outside ``NOISE_DENSITY_RANGE``."""
    low, high = NOISE_DENSITY_RANGE[sensor]
    unit = "rad/s/sqrt(Hz)" if sensor == "gyro" else "m/s^2/sqrt(Hz)"
    number = isinstance(sigma, int | float) and not isinstance(sigma, bool)
    if not (number and math.isfinite(sigma) and low <= sigma <= high):
        hint = " (a variance, sigma^2? give sigma)" if number and 0 < sigma < low else ""
        raise ConfigError(
            f"{where}: {sigma!r} is not a {sensor} noise density sigma in [{low:g}, {high:g}] {unit}{hint}"
        )


def renamed(data: dict, where: str = "") -> dict:
    """``data`` (a stored config mapping, e.g. a checkpoint's) with renamed keys moved to their new names."""
    out = {}
    for key, value in data.items():
        new = RENAMED_KEYS.get(key, (key,))[0]
        out[new] = renamed(value) if isinstance(value, dict) else value
    return out


def from_dict(cls, data, source: str = "config", where: str = ""):
    """Build dataclass ``cls`` from a mapping, checking every key and type (errors name ``source`` and the key)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {where or 'top level'}: expected a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    for key in data:
        if key in RENAMED_KEYS and RENAMED_KEYS[key][0] in known:
            new, meaning = RENAMED_KEYS[key]
            raise ConfigError(f"{source}: key '{_join(where, key)}' is now '{_join(where, new)}' ({meaning})")
        if key not in known:
            raise ConfigError(
                f"{source}: unknown key '{_join(where, key)}'; known keys here: {', '.join(sorted(known))}"
            )
    values = {}
    for name, f in known.items():
        key = _join(where, name)
        if name in data:
            values[name] = _convert(hints[name], data[name], source, key)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{source}: missing key '{key}'")
    try:
        return cls(**values)
    except ConfigError as error:  # a record's own range check (__post_init__)
        raise ConfigError(f"{source}: key '{where or 'top level'}': {error}") from None


def to_dict(config) -> dict:
    """Plain dict (tuples as lists) for YAML/JSON; ``from_dict`` inverts it."""

    def plain(value):
        if isinstance(value, tuple | list):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return plain(dataclasses.asdict(config))


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else str(key)


def _convert(hint, value, source: str, key: str):
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if dataclasses.is_dataclass(hint):
        return from_dict(hint, value, source, key)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{source}: key '{key}': expected a list, got {value!r}")
        return tuple(_convert(args[0], v, source, f"{key}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
            raise ConfigError(f"{source}: key '{key}': expected a mapping with string keys, got {value!r}")
        return dict(value)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        members = [a for a in args if a is not type(None)]
        if len(members) == 1:
            return _convert(members[0], value, source, key)
        for member in members:  # the first member that reads the value (a number, or a list of them)
            try:
                return _convert(member, value, source, key)
            except ConfigError:
                pass
        names = " or ".join("a list" if typing.get_origin(m) is tuple else m.__name__ for m in members)
        raise ConfigError(f"{source}: key '{key}': expected {names}, got {value!r} ({type(value).__name__})")
    if origin is Literal:  # one of a fixed set of values
        if value in args:
            return value
        raise ConfigError(f"{source}: key '{key}': expected one of {', '.join(map(str, args))}, got {value!r}")
    if hint is Any:
        return value
    if hint is float and isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if hint is float and isinstance(value, str):  # PyYAML reads 1e-3 (no dot) as a string
        try:
            return float(value)
        except ValueError:
            pass
    if hint is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if hint in (bool, str) and isinstance(value, hint):
        return value
    raise ConfigError(f"{source}: key '{key}': expected {hint.__name__}, got {value!r} ({type(value).__name__})")


def save_yaml(path: str | Path, config) -> None:
    """Write a config dataclass as YAML (``to_dict``), atomically."""
    from airimu_core.io import atomic_file

    with atomic_file(path) as f:
        yaml.safe_dump(to_dict(config), f, sort_keys=False)
