"""Dormand-Prince 8(5,3) with dense output: the adaptive integrator of rollouts and replays,
written here so that a command does not import ``scipy.integrate`` (0.3-0.6 s with the
``scipy.linalg`` and ``scipy.optimize`` it pulls in).

The scheme is Hairer's DOP853 (E. Hairer, S. P. Norsett, G. Wanner, "Solving Ordinary
Differential Equations I", Sec. II.5 and II.10), step for step as SciPy's ``solve_ivp(...,
method="DOP853", t_eval=...)`` runs it: the same coefficients, initial step, error norm (the
5th-order estimate corrected by the 3rd-order one), step-size control and 7th-order dense
output at the output times, with the arithmetic in the same order, so its numbers are SciPy's
(``tests/test_dop853.py`` compares them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: Step-size control: safety factor, bounds of one step's change.
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
#: Stages of a step (the 13th, at the new state, is the next step's first) and of the dense
#: output (3 more).
N_STAGES = 12
N_STAGES_EXTENDED = 16
INTERPOLATOR_POWER = 7
#: Why :func:`solve` stopped, by status (SciPy's words).
MESSAGES = {
    0: "The solver successfully reached the end of the integration interval.",
    -1: "Required step size is less than spacing between numbers.",
}
#: The error estimator's order: steps scale with the error to the power -1/8.
ERROR_EXPONENT = -1 / 8

# Coefficients (nodes, stage matrix, dense-output matrix, error weights), as Hairer's DOP853.
_C = (
    0.0,
    0.05260015195876773,
    0.0789002279381516,
    0.1183503419072274,
    0.2816496580927726,
    0.3333333333333333,
    0.25,
    0.3076923076923077,
    0.6512820512820513,
    0.6,
    0.8571428571428571,
    1.0,
    1.0,
    0.1,
    0.2,
    0.7777777777777778,
)
_A_ROWS = {
    1: {0: 0.05260015195876773},
    2: {0: 0.0197250569845379, 1: 0.0591751709536137},
    3: {0: 0.02958758547680685, 2: 0.08876275643042054},
    4: {0: 0.2413651341592667, 2: -0.8845494793282861, 3: 0.924834003261792},
    5: {0: 0.037037037037037035, 3: 0.17082860872947386, 4: 0.12546768756682242},
    6: {0: 0.037109375, 3: 0.17025221101954405, 4: 0.06021653898045596, 5: -0.017578125},
    7: {
        0: 0.03709200011850479,
        3: 0.17038392571223998,
        4: 0.10726203044637328,
        5: -0.015319437748624402,
        6: 0.008273789163814023,
    },
    8: {
        0: 0.6241109587160757,
        3: -3.3608926294469414,
        4: -0.868219346841726,
        5: 27.59209969944671,
        6: 20.154067550477894,
        7: -43.48988418106996,
    },
    9: {
        0: 0.47766253643826434,
        3: -2.4881146199716677,
        4: -0.590290826836843,
        5: 21.230051448181193,
        6: 15.279233632882423,
        7: -33.28821096898486,
        8: -0.020331201708508627,
    },
    10: {
        0: -0.9371424300859873,
        3: 5.186372428844064,
        4: 1.0914373489967295,
        5: -8.149787010746927,
        6: -18.52006565999696,
        7: 22.739487099350505,
        8: 2.4936055526796523,
        9: -3.0467644718982196,
    },
    11: {
        0: 2.273310147516538,
        3: -10.53449546673725,
        4: -2.0008720582248625,
        5: -17.9589318631188,
        6: 27.94888452941996,
        7: -2.8589982771350235,
        8: -8.87285693353063,
        9: 12.360567175794303,
        10: 0.6433927460157636,
    },
    12: {
        0: 0.054293734116568765,
        5: 4.450312892752409,
        6: 1.8915178993145003,
        7: -5.801203960010585,
        8: 0.3111643669578199,
        9: -0.1521609496625161,
        10: 0.20136540080403034,
        11: 0.04471061572777259,
    },
    13: {
        0: 0.056167502283047954,
        6: 0.25350021021662483,
        7: -0.2462390374708025,
        8: -0.12419142326381637,
        9: 0.15329179827876568,
        10: 0.00820105229563469,
        11: 0.007567897660545699,
        12: -0.008298,
    },
    14: {
        0: 0.03183464816350214,
        5: 0.028300909672366776,
        6: 0.053541988307438566,
        7: -0.05492374857139099,
        10: -0.00010834732869724932,
        11: 0.0003825710908356584,
        12: -0.00034046500868740456,
        13: 0.1413124436746325,
    },
    15: {
        0: -0.42889630158379194,
        5: -4.697621415361164,
        6: 7.683421196062599,
        7: 4.06898981839711,
        8: 0.3567271874552811,
        12: -0.0013990241651590145,
        13: 2.9475147891527724,
        14: -9.15095847217987,
    },
}
_D_ROWS = {
    0: {
        0: -8.428938276109013,
        5: 0.5667149535193777,
        6: -3.0689499459498917,
        7: 2.38466765651207,
        8: 2.117034582445028,
        9: -0.871391583777973,
        10: 2.2404374302607883,
        11: 0.6315787787694688,
        12: -0.08899033645133331,
        13: 18.148505520854727,
        14: -9.194632392478356,
        15: -4.436036387594894,
    },
    1: {
        0: 10.427508642579134,
        5: 242.28349177525817,
        6: 165.20045171727028,
        7: -374.5467547226902,
        8: -22.113666853125306,
        9: 7.733432668472264,
        10: -30.674084731089398,
        11: -9.332130526430229,
        12: 15.697238121770845,
        13: -31.139403219565178,
        14: -9.35292435884448,
        15: 35.81684148639408,
    },
    2: {
        0: 19.985053242002433,
        5: -387.0373087493518,
        6: -189.17813819516758,
        7: 527.8081592054236,
        8: -11.57390253995963,
        9: 6.8812326946963,
        10: -1.0006050966910838,
        11: 0.7777137798053443,
        12: -2.778205752353508,
        13: -60.19669523126412,
        14: 84.32040550667716,
        15: 11.99229113618279,
    },
    3: {
        0: -25.69393346270375,
        5: -154.18974869023643,
        6: -231.5293791760455,
        7: 357.6391179106141,
        8: 93.40532418362432,
        9: -37.45832313645163,
        10: 104.0996495089623,
        11: 29.8402934266605,
        12: -43.53345659001114,
        13: 96.32455395918828,
        14: -39.17726167561544,
        15: -149.72683625798564,
    },
}
_E3_MINUS_B = {0: 0.2440944881889764, 8: 0.7338466882816118, 11: 0.022058823529411766}
_E5 = {
    0: 0.01312004499419488,
    5: -1.2251564463762044,
    6: -0.4957589496572502,
    7: 1.6643771824549864,
    8: -0.35032884874997366,
    9: 0.3341791187130175,
    10: 0.08192320648511571,
    11: -0.022355307863886294,
}


def _dense(rows: dict[int, dict[int, float]], shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros(shape)
    for i, row in rows.items():
        for j, value in row.items():
            out[i, j] = value
    return out


_A_FULL = _dense(_A_ROWS, (N_STAGES_EXTENDED, N_STAGES_EXTENDED))
_C_FULL = np.array(_C)
A = _A_FULL[:N_STAGES, :N_STAGES]
B = _A_FULL[N_STAGES, :N_STAGES]
C = _C_FULL[:N_STAGES]
A_EXTRA, C_EXTRA = _A_FULL[N_STAGES + 1 :], _C_FULL[N_STAGES + 1 :]
D = _dense(_D_ROWS, (INTERPOLATOR_POWER - 3, N_STAGES_EXTENDED))
E3 = np.zeros(N_STAGES + 1)
E3[:-1] = B
for _j, _v in _E3_MINUS_B.items():
    E3[_j] -= _v
E5 = np.zeros(N_STAGES + 1)
for _j, _v in _E5.items():
    E5[_j] = _v


@dataclass
class Solution:
    """What :func:`solve` returns (the fields of ``solve_ivp``'s result that balance-opt reads).

    Attributes:
        t: the output times reached (T',).
        y: the states there (ny, T').
        nfev: right-hand side evaluations.
        status: 0 reached the end, -1 a step fell below the smallest the time allows.
        message: why it stopped.
    """

    t: np.ndarray
    y: np.ndarray
    nfev: int
    status: int
    message: str


def _rms(x: np.ndarray) -> float:
    return np.linalg.norm(x) / x.size**0.5


def _initial_step(fun, t0, y0, f0, t_bound, max_step, rtol, atol) -> float:
    """Hairer's starting step (the same as SciPy's ``select_initial_step``)."""
    interval = abs(t_bound - t0)
    if interval == 0.0:
        return 0.0
    scale = atol + np.abs(y0) * rtol
    d0, d1 = _rms(y0 / scale), _rms(f0 / scale)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, interval)
    f1 = fun(t0 + h0, y0 + h0 * f0)
    d2 = _rms((f1 - f0) / scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1 / 8)
    return min(100 * h0, h1, interval, max_step)


def _error_norm(K: np.ndarray, h: float, scale: np.ndarray) -> float:
    err5 = np.dot(K.T, E5) / scale
    err3 = np.dot(K.T, E3) / scale
    err5_2, err3_2 = np.linalg.norm(err5) ** 2, np.linalg.norm(err3) ** 2
    if err5_2 == 0 and err3_2 == 0:
        return 0.0
    return np.abs(h) * err5_2 / np.sqrt((err5_2 + 0.01 * err3_2) * len(scale))


def _stages(fun, t, y, h, K, A_rows, C_nodes, first: int) -> None:
    """Stages ``first, first + 1, ...`` of a step of ``h`` from ``(t, y)`` into ``K``."""
    for s, (a, c) in enumerate(zip(A_rows, C_nodes), start=first):
        K[s] = fun(t + c * h, y + np.dot(K[:s].T, a[:s]) * h)


def _interpolate(fun, t_old, y_old, t, y, f, h, K, t_out) -> np.ndarray:
    """The 7th-order dense output of the step ``t_old -> t`` at ``t_out`` (ny, len(t_out))."""
    _stages(fun, t_old, y_old, h, K, A_EXTRA, C_EXTRA, N_STAGES + 1)
    F = np.empty((INTERPOLATOR_POWER, y.size))
    delta_y = y - y_old
    F[0] = delta_y
    F[1] = h * K[0] - delta_y
    F[2] = 2 * delta_y - h * (f + K[0])
    F[3:] = h * np.dot(D, K)
    x = ((t_out - t_old) / (t - t_old))[:, None]
    out = np.zeros((x.size, y.size))
    for i, row in enumerate(reversed(F)):
        out += row
        out *= x if i % 2 == 0 else 1 - x
    out += y_old
    return out.T


def solve(
    rhs: Callable[[float, np.ndarray], np.ndarray],
    y0: np.ndarray,
    t_eval: np.ndarray,
    rtol: float,
    atol: float,
    max_step: float = np.inf,
) -> Solution:
    """Integrate ``y' = rhs(t, y)`` from ``t_eval[0]`` to ``t_eval[-1]`` (increasing).

    Args:
        rhs: right-hand side ``(t [s], y) -> y'``.
        y0: the state at ``t_eval[0]``.
        t_eval: output times [s], increasing.
        rtol, atol: relative and absolute tolerances per component.
        max_step: largest step [s].

    Returns:
        The states at the output times reached (all of them when ``status`` is 0).
    """
    nfev = 0

    def fun(t, y):
        nonlocal nfev
        nfev += 1
        return np.asarray(rhs(t, y), dtype=float)

    t_eval = np.asarray(t_eval, dtype=float)
    t, t_bound = float(t_eval[0]), float(t_eval[-1])
    y = np.array(y0, dtype=float)
    f = fun(t, y)
    h_abs = _initial_step(fun, t, y, f, t_bound, max_step, rtol, atol)
    K = np.empty((N_STAGES_EXTENDED, y.size))
    ts, ys, i_out, status = [], [], 0, None
    while status is None:
        if t == t_bound:
            status = 0
            break
        min_step = 10 * np.abs(np.nextafter(t, np.inf) - t)
        h_abs = min(max(h_abs, min_step), max_step)
        rejected = False
        while True:
            if h_abs < min_step:
                status = -1
                break
            t_new = min(t + h_abs, t_bound)
            h = t_new - t
            h_abs = np.abs(h)
            K[0] = f
            _stages(fun, t, y, h, K, A[1:], C[1:], 1)
            y_new = y + h * np.dot(K[:N_STAGES].T, B)
            f_new = fun(t + h, y_new)
            K[N_STAGES] = f_new
            scale = atol + np.maximum(np.abs(y), np.abs(y_new)) * rtol
            error = _error_norm(K[: N_STAGES + 1], h, scale)
            if error < 1:
                factor = (
                    MAX_FACTOR if error == 0 else min(MAX_FACTOR, SAFETY * error**ERROR_EXPONENT)
                )
                h_abs *= min(1, factor) if rejected else factor
                break
            h_abs *= max(MIN_FACTOR, SAFETY * error**ERROR_EXPONENT)
            rejected = True
        if status == -1:
            break
        i_new = np.searchsorted(t_eval, t_new, side="right")
        if i_new > i_out:
            ts.append(t_eval[i_out:i_new])
            ys.append(_interpolate(fun, t, y, t_new, y_new, f_new, h, K, t_eval[i_out:i_new]))
            i_out = i_new
        t, y, f = t_new, y_new, f_new
        if t >= t_bound:
            status = 0
    message = MESSAGES[status]
    if not ts:
        return Solution(np.empty(0), np.empty((y.size, 0)), nfev, status, message)
    return Solution(np.hstack(ts), np.hstack(ys), nfev, status, message)
