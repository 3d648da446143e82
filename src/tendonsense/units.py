"""Units shown to users: forces in N and gram-force, lengths in m and mm (no JAX, no numpy)."""

import math

#: 1 gram-force in newtons
GF = 9.80665e-3


def newtons(value: float, sigma: float | None = None) -> str:
    """A force with its unit and gram-force, e.g. ``0.0759 N (7.7 gF) ± 0.0027 N (0.3 gF)``."""
    text = f"{value:.4g} N ({value / GF:.1f} gF)"
    if sigma is not None:
        text += f" ± {sigma:.2g} N ({sigma / GF:.1f} gF)"
    return text


def between(low: float, high: float, text=newtons) -> str:
    """A range, open where it is infinite, its ends written by ``text`` (default a force:
    ``between 0.0756 N (7.7 gF) and 0.492 N (50.2 gF)``)."""
    if math.isfinite(low) and math.isfinite(high):
        return f"between {text(low)} and {text(high)}"
    if math.isfinite(low):
        return f"at least {text(low)}"
    if math.isfinite(high):
        return f"at most {text(high)}"
    return "unbounded"
