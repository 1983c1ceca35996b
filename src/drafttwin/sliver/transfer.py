"""From a roller's speed to the sliver's mass: the drafting transfer (closed form).

Ideal drafting in every zone and small relative speed modulations ``u_k`` of the rollers'
surface speeds give a relative modulation of the delivered fibre-end density (research/
sliver.md 4.4), in delivered length ``s`` with the zones' transit lengths
``d2 = g_main D_main`` and ``d3 = g_middle D_middle D_main``::

    dn/n(s) = u_back(s-d2-d3) - u_third(s-d2-d3) + u_third(s-d2) - u_second(s-d2)
              + u_second(s) - u_front(s)

so at wavelength ``lambda`` (``kappa = 2 pi / lambda``) each roller has a complex gain
``H_front = -1``, ``H_second = 1 - exp(-i kappa d2)``, ``H_third = exp(-i kappa d2) -
exp(-i kappa (d2+d3))``, ``H_back = exp(-i kappa (d2+d3))``. They add up to zero: a speed
modulation shared by every roller (the motor, the main belt) changes no draft and leaves no
mass modulation in ideal drafting. The mass is the fibre-end density smoothed over the fibre
lengths, each fibre reaching from its leading end back over its own length, so
``H_l = sum(w l sinc(l/lambda) exp(-i pi l/lambda)) / sum(w l)`` (number weights ``w``),
which buries waves shorter than the fibres. Its magnitude is below the real form
``sum(w l sinc(l/lambda)) / sum(w l)`` of research/sliver.md 4.4 where lengths differ (fibres
of different lengths centre their mass at different distances behind their leading ends):
for the cotton preset 0.535 against 0.585 at 5 cm, 0.960 against 0.968 at 20 cm; the
drafting simulator agrees with the complex form (tests/sliver).
"""

from __future__ import annotations

import numpy as np

from drafttwin.sliver.staple import StapleDiagram

ROLLERS = ("front", "second", "third", "back")


def fibre_length_gain(staple: StapleDiagram, wavelength_m: np.ndarray | float) -> np.ndarray:
    """``H_l(lambda)`` (complex): the mass-weighted mean of ``sinc(l/lambda) exp(-i pi
    l/lambda)`` over the staple, from fibre-end density to mass."""
    lam = np.atleast_1d(np.asarray(wavelength_m, dtype=np.float64))
    l_m = staple.lengths_mm * 1e-3
    w = staple.weights * l_m
    x = l_m[None, :] / lam[:, None]
    return np.asarray((np.sinc(x) * np.exp(-1j * np.pi * x)) @ w / w.sum())


def roller_gains(wavelength_m: np.ndarray | float, transit_m: tuple[float, float]) -> np.ndarray:
    """Complex gains ``(n, 4)`` of front, second, third, back from relative surface-speed
    modulation to relative fibre-end density, for delivered transit lengths ``(d2, d3)``
    (m) of the main and middle zones."""
    lam = np.atleast_1d(np.asarray(wavelength_m, dtype=np.float64))
    kappa = 2 * np.pi / lam
    e2 = np.exp(-1j * kappa * transit_m[0])
    e23 = np.exp(-1j * kappa * (transit_m[0] + transit_m[1]))
    return np.column_stack([-np.ones_like(e2), 1 - e2, e2 - e23, e23])


def transit_lengths_m(gauges_mm: tuple[float, float, float],
                      drafts: dict[str, float]) -> tuple[float, float]:  # fmt: skip
    """Delivered lengths ``(d2, d3)``, m, that the main and middle zones' transits take:
    the gauge (mm) times the draft from the zone's feeding roller to the front."""
    main, middle = gauges_mm[0] * 1e-3, gauges_mm[1] * 1e-3
    return main * drafts["main"], middle * drafts["main"] * drafts["middle"]


def mass_gain(rollers: dict[str, float], wavelength_m: np.ndarray | float,
              gauges_mm: tuple[float, float, float], drafts: dict[str, float],
              staple: StapleDiagram) -> np.ndarray:  # fmt: skip
    """Complex gain from a common relative speed modulation ``u`` to the relative mass
    modulation of the delivered sliver, when roller ``k`` moves by ``rollers[k] * u``
    (1 for the rollers an element drives, 0 for the others)."""
    c = np.array([rollers.get(r, 0.0) for r in ROLLERS])
    g = roller_gains(wavelength_m, transit_lengths_m(gauges_mm, drafts)) @ c
    return np.asarray(g * fibre_length_gain(staple, wavelength_m))
