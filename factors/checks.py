"""Checks to run before an optimiser: every key a factor uses must have a value of the right type."""

from __future__ import annotations

import gtsam


class GraphError(ValueError):
    """A factor graph and its initial values do not fit together; the message names the key and the factor."""


def key_name(key: int) -> str:
    """``x3``-style name of a symbol key (``gtsam.symbol_shorthand``), else the integer."""
    symbol = gtsam.Symbol(key)
    char = symbol.chr()
    return f"{chr(char) if isinstance(char, int) else char}{symbol.index()}" if char else str(key)


def check_values(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """Raise ``GraphError`` naming the first missing key and the factor that needs it; and the first key that
    no factor uses (an unconstrained variable makes the linear system indeterminate)."""
    used = set()
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None:
            continue
        for key in factor.keys():
            used.add(key)
            if not values.exists(key):
                raise GraphError(
                    f"factor {i} ({type(factor).__name__}) needs a value for {key_name(key)}, "
                    "which the initial values do not have"
                )
    unused = [key for key in values.keys() if key not in used]
    if unused:
        raise GraphError(f"{key_name(unused[0])} has an initial value but no factor constrains it")
