"""One colour per setting, shared by the Rerun recording and the PNG figures (no rerun or matplotlib here).

A colour family per kind of IMU input: blues for AirIMU-corrected samples, reds and oranges for the raw IMU, greens
for anything else (GTSAM's example settings, a single ``airimu fuse`` run); inside a family the shade says the
covariance (learned: deep, fixed: light) and bias states (a second pair of shades). Ground truth is near black,
GPS magenta; x/y/z are red/green/blue in every plot. Colours are (r, g, b), 0-255.
"""

from __future__ import annotations

RGB = tuple[int, int, int]

GROUND_TRUTH: RGB = (25, 25, 25)
GPS: RGB = (200, 0, 160)
OUTAGE: RGB = (150, 150, 150)  # GPS outages: a grey band
AXES: tuple[RGB, RGB, RGB] = ((214, 39, 40), (44, 160, 44), (31, 119, 180))  # x, y, z
AXIS_NAMES = ("x", "y", "z")
TRAIN: RGB = (60, 60, 60)  # training curves: the training set dark, the validation set orange
VALIDATION: RGB = (230, 120, 0)

# shades per family, in the order learned, fixed, learned + bias, fixed + bias
FAMILIES: dict[str, tuple[RGB, RGB, RGB, RGB]] = {
    "airimu": ((28, 76, 160), (90, 160, 225), (0, 128, 128), (90, 190, 180)),
    "raw": ((200, 40, 30), (245, 140, 40), (140, 60, 20), (225, 175, 50)),
    "other": ((40, 140, 60), (130, 195, 100), (100, 100, 40), (170, 170, 90)),
}

# the setting shown first (its ellipsoids visible by default): the paper's method
HEADLINE = "AirIMU + learned cov"


def family(name: str) -> str:
    """``"airimu"``, ``"raw"`` or ``"other"`` from a setting's name (``"AirIMU + fixed cov"``, ``"raw IMU"``...)."""
    lowered = name.lower()
    if lowered.startswith("airimu"):
        return "airimu"
    if lowered.startswith("raw"):
        return "raw"
    return "other"


def setting_color(name: str) -> RGB:
    """The colour of a setting: its family, and a shade by covariance (learned/fixed) and bias states."""
    lowered = name.lower()
    shade = (1 if "fixed" in lowered else 0) + (2 if "bias" in lowered else 0)
    return FAMILIES[family(name)][shade]


def setting_colors(names: list[str]) -> dict[str, RGB]:
    """A colour per name; two names that would share one (e.g. two settings outside the families) are told apart
    by the next free shade of their family."""
    out: dict[str, RGB] = {}
    for name in names:
        color = setting_color(name)
        if color in out.values():
            free = [c for f in (family(name), "other") for c in FAMILIES[f] if c not in out.values()]
            color = free[0] if free else color
        out[name] = color
    return out


def headline(names: list[str]) -> str | None:
    """The setting whose uncertainty is shown by default: ``HEADLINE`` if present, else the first."""
    return HEADLINE if HEADLINE in names else (names[0] if names else None)


def lighter(color: RGB, amount: float = 0.5) -> RGB:
    """``color`` mixed with white (``amount`` 0: unchanged, 1: white)."""
    r, g, b = (round(c + (255 - c) * amount) for c in color)
    return (r, g, b)
