# ruff: noqa: E501, E702, UP031  (throwaway probes of issue 37, kept to be rerun, not polished)
import numpy as np


def deep(x):
    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, tuple) and hasattr(x, "_fields"):
        return type(x)(*[deep(v) for v in x])
    if isinstance(x, tuple):
        return tuple(deep(v) for v in x)
    return x
