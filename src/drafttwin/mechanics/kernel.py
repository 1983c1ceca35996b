"""The numba-compiled right-hand sides and the one fixed-step RK4 loop.

``rhs`` (full train) and ``reduced_rhs`` (stiff couplings rigid, :mod:`reduced`) each take the
train as one bundle (:class:`TrainTables`, :class:`ReducedTables`); ``_rk4`` is the RK4 loop,
written once and inlined into the two cached kernels ``integrate`` and ``integrate_reduced``,
each with its derivative.

State vector layout (float64), for ``n`` nodes, ``nb`` belts, ``nm`` motors::

    [ theta (n) | omega (n) | belt stretch (nb) | motor torque (nm) | motor phase (nm) | energy (5) ]

``energy`` accumulates, in joules: 0 motor work, 1 roller friction-load work, 2 bearing losses,
3 coupling dissipation (damping and belt creep), 4 work done by external torques. They are
integrated by the same RK4, so the power balance can be checked without extra sampling.

Element tables are plain arrays with the column layout below; :mod:`assembly` fills them and
bundles them (:meth:`~drafttwin.mechanics.assembly.Tables.kernel`).
Angles reach ~1e4 rad in a minute, so everything stays float64 (float32 round-off would be
the size of the tooth deflections).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

N_ENERGY = 5
NH_MAX = 12  # most mesh-stiffness harmonics a gear may carry

# motor_i: node, supply signal, rotor-resistance signal; motor_f: breakdown torque (N m),
# breakdown slip speed (rad/s, V/f-constant Kloss in slip speed), pole pairs, lag (s),
# ripple amplitude, constant supply frequency (Hz)
MOT_TK, MOT_SK, MOT_PP, MOT_TAU, MOT_RIPPLE, MOT_F = range(6)
# belt_f: driver radius, driven radius, span stiffness, damping, 1/axial rigidity
BELT_RA, BELT_RB, BELT_K, BELT_C, BELT_INV_EA = range(5)
# chain_f: teeth a, teeth b, pitch, pitch radius a, pitch radius b, span k, span c, pretension
CH_ZA, CH_ZB, CH_P, CH_RA, CH_RB, CH_K, CH_C, CH_T0 = range(8)
# gear_f: base radii, driver teeth, mean k, c, half backlash, eccentricities + phases, TE,
# then NH_MAX cosine and NH_MAX sine coefficients of k(mesh phase) (gear_i[:, 2] = harmonics),
# then a tooth fault on the driver gear (0 = none, the assembled default; see plant faults):
# stiffness loss fraction while that tooth is in mesh, its angle, the driver angle it stays in mesh
(G_RBA, G_RBB, G_ZA, G_K, G_C, G_B, G_EA, G_PA, G_EB, G_PB, G_TE) = range(11)
G_COEF = 11
G_CRACK = G_COEF + 2 * NH_MAX
G_CRACK_ANGLE, G_CRACK_SPAN = G_CRACK + 1, G_CRACK + 2
GEAR_COLS = G_CRACK + 3
# spring_f: k, c ; drag_f: coulomb torque, speed eps, viscous, kind (0 load, 1 bearing)
DR_COUL, DR_EPS, DR_VISC, DR_KIND = range(4)


class TrainTables(NamedTuple):
    """The drive train's element tables as one bundle (numba passes a named tuple of arrays
    as one struct: no copy, fields read as cheaply as separate arguments).

    ``*_i`` are int64 rows (nodes, signal rows), ``*_f`` float64 rows in the column layouts
    above; ``spring``: k, c; ``torque_f``: gain; ``sig_i``: start, length, zero-order hold;
    ``sig_f``: t0, dt; ``sig_v``: all signals' values, one after another.
    """

    inv_j: np.ndarray
    motor_i: np.ndarray
    motor_f: np.ndarray
    belt_i: np.ndarray
    belt_f: np.ndarray
    chain_i: np.ndarray
    chain_f: np.ndarray
    gear_i: np.ndarray
    gear_f: np.ndarray
    spring_i: np.ndarray
    spring_f: np.ndarray
    drag_i: np.ndarray
    drag_f: np.ndarray
    torque_i: np.ndarray
    torque_f: np.ndarray
    sig_i: np.ndarray
    sig_f: np.ndarray
    sig_v: np.ndarray


class ReducedTables(NamedTuple):
    """A reduced train (see :mod:`drafttwin.mechanics.reduced`) as one bundle: node ``i``
    turns as ``ratio[i] * Theta[cluster[i]] + offset[i]``; ``inv_jc`` is 1 / the super-nodes'
    inertias; ``tables`` are the remaining couplings' (``inv_j`` all ones: :func:`rhs` then
    returns node torques, which the reduced right-hand side reflects onto the super-nodes);
    ``work``: scratch of shape ``(2, len(full state))`` for the expanded state and its
    derivative."""

    cluster: np.ndarray
    ratio: np.ndarray
    offset: np.ndarray
    inv_jc: np.ndarray
    tables: TrainTables
    work: np.ndarray


@njit(cache=True, error_model="numpy", inline="always")
def _signal(k, t, tab):
    """Signal ``k`` at time ``t``: linear or zero-order hold on its uniform grid, clamped."""
    sig_i, sig_f, sig_v = tab.sig_i, tab.sig_f, tab.sig_v
    start = sig_i[k, 0]
    length = sig_i[k, 1]
    u = (t - sig_f[k, 0]) / sig_f[k, 1]
    if u <= 0.0:
        return sig_v[start]
    if u >= length - 1:
        return sig_v[start + length - 1]
    if sig_i[k, 2] == 1:  # zero-order hold; the tolerance keeps sample instants on their sample
        return sig_v[start + int(u + 1e-9)]
    j = int(u)
    w = u - j
    return sig_v[start + j] * (1.0 - w) + sig_v[start + j + 1] * w


# inlined into the RK4 stage loop of integrate (about 15 % faster than a call per stage);
# still callable from Python for the SciPy reference integrator
@njit(cache=True, error_model="numpy", inline="always")
def rhs(t, y, dy, tab):
    """d y / d t of the full train into ``dy`` (``tab``: its :class:`TrainTables`)."""
    (inv_j, motor_i, motor_f, belt_i, belt_f, chain_i, chain_f, gear_i, gear_f,
     spring_i, spring_f, drag_i, drag_f, torque_i, torque_f) = tab[:15]  # fmt: skip
    n = inv_j.shape[0]
    nb = belt_i.shape[0]
    nm = motor_i.shape[0]
    o_w = n
    o_belt = 2 * n
    o_mt = o_belt + nb
    o_mp = o_mt + nm
    o_e = o_mp + nm
    for i in range(n):
        dy[i] = y[o_w + i]
        dy[o_w + i] = 0.0  # net torque first, divided by J at the end
    for k in range(N_ENERGY):
        dy[o_e + k] = 0.0

    for m in range(nm):
        node = motor_i[m, 0]
        f = motor_f[m, MOT_F] if motor_i[m, 1] < 0 else _signal(motor_i[m, 1], t, tab)
        rr = 1.0 if motor_i[m, 2] < 0 else _signal(motor_i[m, 2], t, tab)
        w_sync = 2.0 * math.pi * f / motor_f[m, MOT_PP]
        s = w_sync - y[o_w + node]  # slip speed, rad/s
        sk = motor_f[m, MOT_SK] * rr  # breakdown slip speed scales with rotor resistance
        t_kloss = 2.0 * motor_f[m, MOT_TK] * s * sk / (s * s + sk * sk)
        t_kloss *= 1.0 + motor_f[m, MOT_RIPPLE] * math.sin(2.0 * y[o_mp + m])
        torque = y[o_mt + m]
        dy[o_mt + m] = (t_kloss - torque) / motor_f[m, MOT_TAU]
        dy[o_mp + m] = 2.0 * math.pi * f
        dy[o_w + node] += torque
        dy[o_e + 0] += torque * y[o_w + node]

    for d in range(drag_i.shape[0]):
        node = drag_i[d, 0]
        w = y[o_w + node]
        torque = drag_f[d, DR_COUL] * _smooth_sign(w / drag_f[d, DR_EPS]) + drag_f[d, DR_VISC] * w
        dy[o_w + node] -= torque
        dy[o_e + 1 + int(drag_f[d, DR_KIND])] += torque * w

    for q in range(torque_i.shape[0]):
        node = torque_i[q, 0]
        torque = torque_f[q, 0] * _signal(torque_i[q, 1], t, tab)
        dy[o_w + node] += torque
        dy[o_e + 4] += torque * y[o_w + node]

    for s_ in range(spring_i.shape[0]):
        a = spring_i[s_, 0]
        b = spring_i[s_, 1]
        rel_w = y[o_w + a] - y[o_w + b]
        torque = spring_f[s_, 0] * (y[a] - y[b]) + spring_f[s_, 1] * rel_w
        dy[o_w + a] -= torque
        dy[o_w + b] += torque
        dy[o_e + 3] += spring_f[s_, 1] * rel_w * rel_w

    for k in range(nb):
        a = belt_i[k, 0]
        b = belt_i[k, 1]
        va = belt_f[k, BELT_RA] * y[o_w + a]
        vb = belt_f[k, BELT_RB] * y[o_w + b]
        f_spring = belt_f[k, BELT_K] * y[o_belt + k]
        creep = f_spring * belt_f[k, BELT_INV_EA]
        stretch_rate = va * (1.0 - creep) - vb
        force = f_spring + belt_f[k, BELT_C] * stretch_rate
        dy[o_belt + k] = stretch_rate
        dy[o_w + a] -= force * belt_f[k, BELT_RA]
        dy[o_w + b] += force * belt_f[k, BELT_RB]
        dy[o_e + 3] += belt_f[k, BELT_C] * stretch_rate * stretch_rate + force * va * creep

    for k in range(chain_i.shape[0]):
        a = chain_i[k, 0]
        b = chain_i[k, 1]
        xa, dxa = _chain_feed(y[a], chain_f[k, CH_ZA], chain_f[k, CH_P], chain_f[k, CH_RA])
        xb, dxb = _chain_feed(y[b], chain_f[k, CH_ZB], chain_f[k, CH_P], chain_f[k, CH_RB])
        stretch = xa - xb
        rate = dxa * y[o_w + a] - dxb * y[o_w + b]
        elastic = chain_f[k, CH_K] * stretch
        damp = chain_f[k, CH_C] * rate
        tight = chain_f[k, CH_T0] + elastic + damp
        slack = chain_f[k, CH_T0] - elastic - damp
        force = 0.0
        if tight > 0.0:
            force += tight
            dy[o_e + 3] += damp * rate
        if slack > 0.0:
            force -= slack
            dy[o_e + 3] += damp * rate
        dy[o_w + a] -= force * dxa
        dy[o_w + b] += force * dxb

    for k in range(gear_i.shape[0]):
        _gear(k, y, dy, o_w, o_e, gear_i, gear_f)

    for i in range(n):
        dy[o_w + i] *= inv_j[i]


@njit(cache=True, error_model="numpy", inline="always")
def _smooth_sign(x):
    """tanh(x), short-cut where it equals +-1 in float64 (|x| > 19.1) because tanh is costly."""
    if x > 20.0:
        return 1.0
    if x < -20.0:
        return -1.0
    return math.tanh(x)


@njit(cache=True, error_model="numpy", inline="always")
def _chain_feed(theta, teeth, pitch, radius):
    """Chain length fed by a sprocket turned by ``theta`` and its derivative d x / d theta."""
    tooth_angle = 2.0 * math.pi / teeth
    u = theta / tooth_angle + 0.5
    n_teeth = math.floor(u)
    phi = (u - n_teeth - 0.5) * tooth_angle
    return pitch * n_teeth + radius * math.sin(phi), radius * math.cos(phi)


@njit(cache=True, error_model="numpy", inline="always")
def _gear(k, y, dy, o_w, o_e, gear_i, gear_f):
    a = gear_i[k, 0]
    b = gear_i[k, 1]
    nh = gear_i[k, 2]
    th_a = y[a]
    th_b = y[b]
    w_a = y[o_w + a]
    w_b = y[o_w + b]
    phase = gear_f[k, G_ZA] * th_a
    c1 = math.cos(phase)
    s1 = math.sin(phase)
    stiff = gear_f[k, G_K]
    cn = 1.0
    sn = 0.0
    for h in range(nh):  # cos/sin of (h+1)*phase by rotation, one sin/cos call per mesh
        cn, sn = cn * c1 - sn * s1, sn * c1 + cn * s1
        stiff += gear_f[k, G_COEF + h] * cn + gear_f[k, G_COEF + NH_MAX + h] * sn
    # a faulty tooth on the driver meshes once per driver revolution
    if (
        gear_f[k, G_CRACK] > 0.0
        and (th_a - gear_f[k, G_CRACK_ANGLE]) % (2.0 * math.pi) < gear_f[k, G_CRACK_SPAN]
    ):
        stiff *= 1.0 - gear_f[k, G_CRACK]
    err = gear_f[k, G_TE] * s1
    err_rate = gear_f[k, G_TE] * c1 * gear_f[k, G_ZA] * w_a
    if gear_f[k, G_EA] > 0.0:
        err += gear_f[k, G_EA] * math.sin(th_a + gear_f[k, G_PA])
        err_rate += gear_f[k, G_EA] * math.cos(th_a + gear_f[k, G_PA]) * w_a
    if gear_f[k, G_EB] > 0.0:
        err += gear_f[k, G_EB] * math.sin(th_b + gear_f[k, G_PB])
        err_rate += gear_f[k, G_EB] * math.cos(th_b + gear_f[k, G_PB]) * w_b
    delta = gear_f[k, G_RBA] * th_a - gear_f[k, G_RBB] * th_b - err
    rate = gear_f[k, G_RBA] * w_a - gear_f[k, G_RBB] * w_b - err_rate
    half = gear_f[k, G_B]
    if delta > half:
        gap = delta - half
    elif delta < -half:
        gap = delta + half
    else:
        return
    elastic = stiff * gap
    force = elastic + gear_f[k, G_C] * rate
    if force * gap <= 0.0:  # damping cannot pull the flanks together (ElastoBacklash)
        return
    dy[o_w + a] -= force * gear_f[k, G_RBA]
    dy[o_w + b] += force * gear_f[k, G_RBB]
    dy[o_e + 3] += (force - elastic) * rate


@njit(cache=True, error_model="numpy")
def reduced_rhs(t, y, dy, model):
    """d y / d t of a reduced train (``model``: its :class:`ReducedTables`): expand ``y`` onto
    the nodes (``model.work[0]``), take the full :func:`rhs` there (node torques into
    ``model.work[1]``), reflect the torques back onto the super-nodes."""
    full = model.work[0]
    dfull = model.work[1]
    cluster, ratio, offset, inv_jc = model.cluster, model.ratio, model.offset, model.inv_jc
    n = cluster.shape[0]
    m = inv_jc.shape[0]
    for i in range(n):
        c = cluster[i]
        full[i] = ratio[i] * y[c] + offset[i]
        full[n + i] = ratio[i] * y[m + c]
    for k in range(y.shape[0] - 2 * m):
        full[2 * n + k] = y[2 * m + k]
    rhs(t, full, dfull, model.tables)
    for c in range(m):
        dy[c] = y[m + c]
        dy[m + c] = 0.0
    for i in range(n):
        dy[m + cluster[i]] += ratio[i] * dfull[n + i]
    for c in range(m):
        dy[m + c] *= inv_jc[c]
    for k in range(y.shape[0] - 2 * m):
        dy[2 * m + k] = dfull[2 * n + k]


# The one RK4 loop. It takes the derivative (and how to record a state) as arguments and is
# inlined (numba IR) into each kernel below, so each kernel is compiled and cached with its
# own functions fixed, and the full rhs is inlined into the stage loop (about 15 % faster
# than a call per stage).
@njit(error_model="numpy", inline="always")
def _rk4(derivative, record, y, t0, dt, steps_per_out, model, out):
    """Advance ``y`` (in place) by ``len(out[0]) * steps_per_out`` RK4 steps of ``dt``
    seconds with ``derivative(t, y, dy, model)``; ``record(model, y, j, out)`` writes the
    state at the end of output interval ``j`` into the output arrays ``out``."""
    m = y.shape[0]
    k = np.empty((4, m))  # the four RK4 stage slopes
    tmp = np.empty(m)
    half = 0.5 * dt
    offset = (0.0, half, half, dt)  # each stage's time (and state step) after t
    for j in range(out[0].shape[0]):
        for step in range(steps_per_out):
            t = t0 + (j * steps_per_out + step) * dt  # no accumulated round-off over 1e6 steps
            for stage in range(4):
                if stage > 0:
                    for i in range(m):
                        tmp[i] = y[i] + offset[stage] * k[stage - 1, i]
                derivative(t + offset[stage], y if stage == 0 else tmp, k[stage], model)
            for i in range(m):
                y[i] += dt / 6.0 * (k[0, i] + 2.0 * k[1, i] + 2.0 * k[2, i] + k[3, i])
        record(model, y, j, out)


@njit(error_model="numpy", inline="always")
def _record_full(tables, y, j, out):
    """Node angles, speeds and energies of the full state ``y`` into row ``j`` of ``out``."""
    theta_out, omega_out, energy_out = out
    n = theta_out.shape[1]
    for i in range(n):
        theta_out[j, i] = y[i]
        omega_out[j, i] = y[n + i]
    for i in range(N_ENERGY):
        energy_out[j, i] = y[y.shape[0] - N_ENERGY + i]


@njit(error_model="numpy", inline="always")
def _record_reduced(model, y, j, out):
    """The same for a reduced state: every original node expanded from its super-node."""
    theta_out, omega_out, energy_out = out
    m = model.inv_jc.shape[0]
    for i in range(theta_out.shape[1]):
        c = model.cluster[i]
        theta_out[j, i] = model.ratio[i] * y[c] + model.offset[i]
        omega_out[j, i] = model.ratio[i] * y[m + c]
    for i in range(N_ENERGY):
        energy_out[j, i] = y[y.shape[0] - N_ENERGY + i]


@njit(cache=True, error_model="numpy", nogil=True)
def integrate(y, t0, dt, n_out, steps_per_out, tables):
    """Advance the full state ``y`` (in place) by ``n_out * steps_per_out`` RK4 steps of
    ``dt`` seconds (``tables``: the train's :class:`TrainTables`).

    Returns the angles (rad) of all nodes at the end of each output interval, their speeds
    (rad/s) at those instants, and the energy accumulators there. Interval means are
    ``diff(theta) / T``, exactly what an encoder counting over the interval reports.
    """
    n = tables.inv_j.shape[0]
    out = (np.empty((n_out, n)), np.empty((n_out, n)), np.empty((n_out, N_ENERGY)))
    _rk4(rhs, _record_full, y, t0, dt, steps_per_out, tables, out)
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def integrate_reduced(y, t0, dt, n_out, steps_per_out, model):
    """:func:`integrate` for the reduced state ``y`` of a :class:`ReducedTables` ``model``:
    the same outputs on every original node (expanded from the super-nodes)."""
    n = model.cluster.shape[0]
    out = (np.empty((n_out, n)), np.empty((n_out, n)), np.empty((n_out, N_ENERGY)))
    _rk4(reduced_rhs, _record_reduced, y, t0, dt, steps_per_out, model, out)
    return out
