"""Units shown to users: forces in N and gram-force, lengths in m and mm (no JAX, no numpy)."""

import math

#: 1 gram-force in newtons
GF = 9.80665e-3


def newtons(value: float, sigma: float | None = None) -> str:
    """A force with its unit and gram-force, e.g. ``0.0759 N (7.7 gF) ± 0.0027 N (0.3 gF)``."""
    text = f"{value:.4g} N ({_grams(value)} gF)"
    return text if sigma is None else f"{text} {spread(sigma)}"


def spread(sigma: float) -> str:
    """A force's 1-σ band, e.g. ``± 0.0027 N (0.3 gF)``; unbounded, ``± ∞`` (readings
    that cannot tell the force's size)."""
    if not math.isfinite(sigma):
        return "± ∞"
    g = sigma / GF
    return f"± {_two(sigma, 1e4)} N ({f'{g:.1f}' if abs(g) < 100 else _two(g, 1e6)} gF)"


def _two(x: float, below: float) -> str:
    """``x`` to two significant digits, without an exponent from 1e-4 up to ``below`` (370,
    not 3.7e+02; newtons up to 1e4 as gram-force up to 1e6, so that both or neither have
    one)."""
    return f"{float(f'{x:.2g}'):g}" if 1e-4 <= abs(x) < below else f"{x:.2g}"


def _grams(force: float) -> str:
    """Gram-force to 0.1 gF, to four digits from a kilogram-force (as the newtons), in powers
    of ten beyond a tonne (a σ that says "unknown")."""
    g = force / GF
    return f"{g:.1f}" if abs(g) < 1e3 else f"{float(f'{g:.4g}'):g}" if abs(g) < 1e6 \
        else f"{g:.2g}"


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


def apart(a: float, b: float) -> tuple[str, str]:
    """``a`` and ``b`` each to two significant digits, or as many more (up to six) as tell
    them apart (a ratio of 1.23 against a limit of 1.18 reads 1.23 and 1.18, not 1.2 twice;
    equal to six digits, six digits each)."""
    digits = next((d for d in range(2, 7) if f"{a:.{d}g}" != f"{b:.{d}g}"), 6)
    sa, sb = f"{a:.{digits}g}", f"{b:.{digits}g}"
    if digits > 2:  # (both to the digits that part them: 1.240 and 1.237)
        sa, sb = (f"{x:#.{digits}g}".rstrip(".") for x in (a, b))
    return sa, sb
