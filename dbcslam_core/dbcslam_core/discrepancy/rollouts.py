"""Open-loop rollouts of the model: pictures of what goes wrong (not evidence).

The evidence of the discrepancy analysis is the filter's predictive likelihood (`scoring`).
This module draws the pictures of the report: from start states along each run (the
filter's posterior means when given, else a local polynomial fit of the observations), the
deterministic model `PlanarModel.step` (vectorised PGS) predicts the next `horizon` samples
from the measured inputs; the residuals obs[k + h] - pred are characterised (bias, growth,
correlations, lag) and plotted by `dbcslam_ros.offline.discrepancy_report`. Friction: the prior
mean of the candidates (a picture of the nominal model, not the filter's estimate).

`Predictor.project` removes the part of each residual that a different start state could
explain (the whitened start-state sensitivities of the nominal model), the "shape" of the
motion over the horizon.

Effects as the rollouts apply them (identical to `PlanarModel(extensions)`): friction fields,
damping, input gain, mass, support friction / pressure, sensor_delay (the model is driven by
the inputs and joints `seconds` earlier), sensor_bias (the prediction is re-biased).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dynamics import PlanarModel, State
from ..errors import DbcSlamError, ModelError
from ..extensions import ModelExtension
from ..geometry import contact_kinematics
from ..lcp import PGSSolver
from ..scenario import Scenario
from .runs import Run, nominal_friction

__all__ = [
    "Prediction",
    "Predictor",
    "RolloutConfig",
    "characterise",
    "mods_of",
    "smooth_states",
]

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass(frozen=True)
class RolloutConfig:
    """Rollout picture settings.

    horizon: rollout length (steps); stride: spacing of rollout starts (steps); max_starts:
    per run (evenly thinned); window/order: local polynomial state estimate (used when no
    filter states are given); pgs_iterations, support_iterations: the predictor's LCP and
    support linearisation iterations; adaptive: one-sided smoothing windows at kinks
    (`smooth_states`); env_window: samples of the centred joint smoothing; profile_start:
    compute the start-state projection (module docstring).
    """

    horizon: int = 20
    stride: int = 2
    max_starts: int = 150
    window: int = 9
    order: int = 2
    pgs_iterations: int = 200
    support_iterations: int = 2
    adaptive: bool = False
    env_window: int = 15
    profile_start: bool = True


def _window_fit(y: F64, dt: float, w: int, order: int, off: I64) -> tuple[F64, F64, F64]:
    """Local polynomial fits on windows starting at k - off[k]: (q, v, rss per sample)."""
    n = y.shape[0]
    idx = np.arange(n)
    start = np.clip(idx - off, 0, max(n - w, 0))
    o = idx - start
    tw = np.arange(w, dtype=np.float64)
    cq = np.zeros((w, w))
    cv = np.zeros((w, w))
    hat = np.zeros((w, w, w))
    for j in range(w):
        vand = np.vander((tw - j) * dt, order + 1, increasing=True)
        pinv = np.linalg.pinv(vand)
        cq[j] = pinv[0]
        cv[j] = pinv[1]
        hat[j] = vand @ pinv
    win = np.minimum(start[:, None] + np.arange(w)[None, :], n - 1)
    yw = y[win]  # (T, w, d)
    q = np.einsum("tw,twd->td", cq[o], yw)
    v = np.einsum("tw,twd->td", cv[o], yw)
    fit = np.einsum("tij,tjd->tid", hat[o], yw)
    rss = np.sum((yw - fit) ** 2, axis=1)  # (T, d)
    return np.asarray(q, np.float64), np.asarray(v, np.float64), np.asarray(rss, np.float64)


def smooth_states(
    obs: F64, dt: float, window: int, order: int, *, adaptive: bool = True
) -> tuple[F64, F64]:
    """Local polynomial (Savitzky-Golay-type) position and velocity estimates.

    obs[T, d] (nan = missing: filled by linear interpolation first); windows of `window`
    samples (shifted inside the series at its ends). adaptive: per sample, the best-fitting
    of the centred, backward and forward windows (smallest residual, each dimension scaled
    by its median residual) so that impacts and stops are not smoothed across.
    Returns q[T, d], v[T, d].
    """
    n, d = obs.shape
    y = np.array(obs, dtype=np.float64)
    idx = np.arange(n)
    for c in range(d):
        ok = np.isfinite(y[:, c])
        if not np.any(ok):
            y[:, c] = 0.0
        elif not np.all(ok):
            y[:, c] = np.interp(idx, idx[ok], y[ok, c])
    w = max(order + 1, min(window, n))
    half = w // 2
    offsets = (half, w - 1, 0) if adaptive else (half,)
    fits = [_window_fit(y, dt, w, order, np.full(n, o, dtype=np.int64)) for o in offsets]
    if len(fits) == 1:
        return fits[0][0], fits[0][1]
    scale = np.maximum(np.median(fits[0][2], axis=0), 1e-30)  # (d,)
    cost = np.stack([np.sum(f[2] / scale, axis=-1) for f in fits])  # (3, T)
    # prefer the centred window unless a one-sided one fits clearly better
    cost[1:] *= 1.5
    pick = np.argmin(cost, axis=0)
    q = np.stack([f[0] for f in fits])[pick, idx]
    v = np.stack([f[1] for f in fits])[pick, idx]
    return np.asarray(q, np.float64), np.asarray(v, np.float64)


# ------------------------------------------------------------------------ effect params
@dataclass(frozen=True)
class Mods:
    """Batched model modifications (leading G) applied by the rollout."""

    scale: F64  # (G,) friction scale
    patch: F64  # (G, 3) x_min, x_max, mu (nan = no patch)
    b: F64  # (G,) viscous damping N s/m
    gain: F64  # (G,) input gain
    delay: F64  # (G,) s
    bias: F64  # (G, 3)
    mu_s: F64  # (G,) support friction (nan = nominal)
    mass: float = 1.0
    rim: float | None = None

    @staticmethod
    def nominal(g: int, mass: float = 1.0, rim: float | None = None) -> Mods:
        return Mods(
            scale=np.ones(g),
            patch=np.full((g, 3), np.nan),
            b=np.zeros(g),
            gain=np.ones(g),
            delay=np.zeros(g),
            bias=np.zeros((g, 3)),
            mu_s=np.full(g, np.nan),
            mass=mass,
            rim=rim,
        )


# ------------------------------------------------------------------------------- predictor
def _noise_scale(sc: Scenario) -> F64:
    """Whitening scale per pose component (m, m, rad): the scenario's observation noise."""
    pos = float(sc.noise.position) if sc.noise.position > 0 else 1e-3
    yaw = float(sc.noise.yaw) if sc.noise.yaw > 0 else 1e-2
    return np.asarray([pos, pos, yaw], dtype=np.float64)


def _velocity_gain(window: int, order: int, dt: float) -> float:
    """Std of the centred local-polynomial velocity estimate per unit observation noise."""
    w = max(order + 1, window)
    tw = (np.arange(w, dtype=np.float64) - w // 2) * dt
    pinv = np.linalg.pinv(np.vander(tw, order + 1, increasing=True))
    return float(np.linalg.norm(pinv[1]))


@dataclass
class _RunData:
    run: Run
    starts: I64  # (S,)
    held: NDArray[np.bool_]  # (S,) start belongs to the held-out set
    q0: F64  # (S, nq) smoothed state at start
    v0: F64
    target: F64  # (S, H, nq) observed poses at k + 1 .. k + H (nan = missing)
    mu_nom: F64  # (P,)
    env_smooth: F64  # (T, E) joint readings smoothed like the poses
    models: dict[tuple[float, float | None], PlanarModel] = field(default_factory=dict)
    basis: F64 | None = None  # (S, H nq, 2 nq) whitened start-state sensitivity basis


@dataclass(frozen=True)
class Prediction:
    """Rollout predictions of one model over all runs (arrays concatenated over runs).

    pred, target, resid [S, H, nq]; held [S]; run_index [S]; t [S] start times (s);
    v0, q0 [S, nq] estimated start state; in_contact [S] (any contact gap <= 1 mm at start);
    shape_resid [S, H, nq] the residuals with the start state profiled out.
    """

    pred: F64
    target: F64
    resid: F64
    held: NDArray[np.bool_]
    run_index: I64
    t: F64
    q0: F64
    v0: F64
    in_contact: NDArray[np.bool_]
    shape_resid: F64 | None = None  # [S, H, nq] start state profiled out (`Predictor.project`)


class Predictor:
    """Batched open-loop rollouts of the (modified) model over a set of runs."""

    def __init__(
        self,
        runs: Sequence[Run],
        heldout: Sequence[bool],
        cfg: RolloutConfig,
        *,
        states: Sequence[tuple[F64, F64] | None] | None = None,
    ) -> None:
        """runs, heldout flags per run; states: per run the filter's posterior mean
        (q, v) [T, nq] used as rollout start states (nan / None: local polynomial fit)."""
        self.cfg = cfg
        self.data: list[_RunData] = []
        h = cfg.horizon
        given = list(states) if states is not None else [None] * len(runs)
        for run, is_held, st in zip(runs, heldout, given, strict=True):
            sc = run.scenario
            n = run.t.shape[0]
            if n < h + cfg.window + 2:
                continue
            obs = np.array(run.obs, dtype=np.float64)
            if sc.nq == 3:
                ok = np.isfinite(obs[:, 2])
                if np.any(ok):
                    obs[ok, 2] = np.unwrap(obs[ok, 2])
            q, v = smooth_states(obs, sc.dt, cfg.window, cfg.order, adaptive=cfg.adaptive)
            if st is not None:
                fin = np.all(np.isfinite(st[0]), -1) & np.all(np.isfinite(st[1]), -1)
                q[fin], v[fin] = st[0][fin], st[1][fin]
            cand = np.arange(cfg.window // 2, n - h - 1, max(cfg.stride, 1))
            cand = cand[np.all(np.isfinite(run.obs[cand]), axis=-1)]
            if cand.size > cfg.max_starts:
                cand = cand[np.linspace(0, cand.size - 1, cfg.max_starts).round().astype(int)]
            if cand.size == 0:
                continue
            held = np.full(cand.size, bool(is_held))
            tgt = obs[cand[:, None] + 1 + np.arange(h)[None, :]]
            self.data.append(
                _RunData(
                    run=run,
                    starts=cand.astype(np.int64),
                    held=held,
                    q0=q[cand],
                    v0=v[cand],
                    target=tgt,
                    mu_nom=nominal_friction(sc),
                    env_smooth=(
                        smooth_states(run.env, sc.dt, cfg.env_window, cfg.order, adaptive=False)[0]
                        if run.env.shape[1]
                        else run.env
                    ),
                )
            )
        if not self.data:
            msg = (
                f"no run is long enough for the analysis (need > {h + cfg.window + 2} "
                "samples with observations)"
            )
            raise ModelError(msg)

        self.white = _noise_scale(self.data[0].run.scenario)
        if cfg.profile_start:
            for d in self.data:
                d.basis = self._start_basis(d)

    @property
    def n_runs(self) -> int:
        return len(self.data)

    def _start_basis(self, d: _RunData) -> F64:
        """Orthonormal basis [S, H nq, r] of the whitened rollout sensitivities to the start
        state (nominal model, central differences of one start-estimate std per coordinate).

        The start state of a rollout is estimated from noisy observations; its error moves the
        whole predicted trajectory along these directions. `project` removes them from the
        residuals (profiles the start state out), so that a candidate cannot win by merely
        shrinking a noisy start velocity (damping, more friction, a delay all stop a noisy
        start faster) and the comparison sees the shape of the motion only.
        """
        sc = d.run.scenario
        nq = sc.nq
        sq = self.white[:nq]
        sv = sq * _velocity_gain(self.cfg.window, self.cfg.order, float(sc.dt))
        step = np.concatenate([sq, sv])
        k = 2 * nq
        dx0 = np.concatenate([np.diag(step), -np.diag(step)])  # (2k, k)
        p = self._rollout_run(d, Mods.nominal(2 * k), dx0)  # (2k, S, H, nq)
        jac = 0.5 * (p[:k] - p[k:]) / self.white[None, None, None, :nq]  # (k, S, H, nq)
        jac = np.nan_to_num(np.moveaxis(jac, 0, -1))  # (S, H, nq, k)
        s_n, hz = jac.shape[0], jac.shape[1]
        jac = jac.reshape(s_n, hz * nq, k)
        u, sv_, _ = np.linalg.svd(jac, full_matrices=False)  # u (S, H nq, k)
        keep = sv_ > 1e-6 * np.maximum(np.max(sv_, axis=-1, keepdims=True), 1e-300)
        return np.asarray(u * keep[:, None, :], dtype=np.float64)

    def project(self, res: list[F64]) -> list[F64]:
        """Residuals [G, S, H, nq] with the start-state directions removed (see
        `_start_basis`), back in the residual units (m, rad); nan entries stay nan."""
        if not self.cfg.profile_start:
            return res
        out = []
        for d, r in zip(self.data, res, strict=True):
            assert d.basis is not None
            g, s_n, hz, nq = r.shape
            w = self.white[:nq]
            bad = ~np.isfinite(r)
            rf = np.where(bad, 0.0, r / w).reshape(g, s_n, hz * nq)
            coef = np.einsum("sjr,gsj->gsr", d.basis, rf)
            rp = (rf - np.einsum("sjr,gsr->gsj", d.basis, coef)).reshape(g, s_n, hz, nq) * w
            rp[bad] = np.nan
            out.append(np.asarray(rp, dtype=np.float64))
        return out

    def _model(self, d: _RunData, mass: float, rim: float | None) -> PlanarModel:
        key = (mass, rim)
        if key not in d.models:
            exts: list[ModelExtension] = []
            if mass != 1.0:
                exts.append(ModelExtension.make("mass_scale", factor=mass))
            if rim is not None:
                exts.append(ModelExtension.make("support_pressure", rim_fraction=rim))
            d.models[key] = PlanarModel(
                d.run.scenario,
                exts,
                PGSSolver(max_iter=self.cfg.pgs_iterations),
                support_iterations=self.cfg.support_iterations,
                support_tol=1e-7,
            )
        return d.models[key]

    def _rollout_run(self, d: _RunData, mods: Mods, dx0: F64 | None = None) -> F64:
        """Predicted observed poses [G, S, H, nq] for one run.

        dx0 [G, 2 nq]: optional offsets of the start state (q, then v) per G (sensitivities).
        """
        run = d.run
        sc = run.scenario
        model = self._model(d, mods.mass, mods.rim)
        g = mods.scale.shape[0]
        s_n = d.starts.shape[0]
        hz = self.cfg.horizon
        nq = sc.nq
        dt = sc.dt
        n = run.t.shape[0]
        # delayed inputs / joints per G (linear interpolation at t - delay)
        tt = np.arange(n, dtype=np.float64)
        shift = mods.delay / dt  # (G,)
        pos = np.clip(tt[None, :] - shift[:, None], 0.0, n - 1.0)  # (G, T)
        lo = np.floor(pos).astype(int)
        hi = np.minimum(lo + 1, n - 1)
        fr = (pos - lo)[..., None]
        u_d = run.u[lo] * (1.0 - fr) + run.u[hi] * fr  # (G, T, nq)
        env = d.env_smooth
        e_d = env[lo] * (1.0 - fr) + env[hi] * fr  # (G, T, E)
        bias = mods.bias[:, :nq]  # (G, nq)
        q = np.broadcast_to(d.q0[None], (g, s_n, nq)) - bias[:, None, :]
        v = np.broadcast_to(d.v0[None], (g, s_n, nq)).copy()
        q = q.copy()
        if dx0 is not None:
            q += dx0[:, None, :nq]
            v += dx0[:, None, nq:]
        pairs = np.asarray(sc.contact_pairs, dtype=np.int64)
        mu_c = d.mu_nom[pairs]  # (C,)
        has_support = model.surface_pair is not None or sc.surface.mu > 0.0
        mu_s_nom = (
            float(d.mu_nom[model.surface_pair])
            if model.surface_pair is not None
            else float(sc.surface.mu)
        )
        mu_s = np.where(np.isnan(mods.mu_s), mu_s_nom, mods.mu_s)
        use_support = has_support or bool(np.any(np.isfinite(mods.mu_s)))
        mus_arr = np.broadcast_to(mu_s[:, None], (g, s_n)) if use_support else None
        gi = np.arange(g)[:, None]
        out = np.zeros((g, s_n, hz, nq))
        patch = mods.patch
        has_patch = bool(np.any(np.isfinite(patch[:, 0])))
        for h in range(hz):
            idx = d.starts + h
            u = u_d[gi, idx[None, :]] * mods.gain[:, None, None]  # (G, S, nq)
            u = u.copy()
            u[..., 0:2] -= mods.b[:, None, None] * v[..., 0:2]
            e0 = e_d[gi, idx[None, :]]
            e1 = e_d[gi, np.minimum(idx + 1, n - 1)[None, :]]
            mu = np.broadcast_to(mu_c * mods.scale[:, None], (g, len(mu_c)))[:, None, :]
            mu = np.broadcast_to(mu, (g, s_n, len(mu_c)))
            if has_patch:
                kin = contact_kinematics(sc, q, e0)
                s = kin.s  # (G, S, C)
                xmin = patch[:, 0][:, None, None]
                xmax = patch[:, 1][:, None, None]
                inside = (s >= xmin) & (s <= xmax) & np.isfinite(xmin)
                mpatch = np.nan_to_num(patch[:, 2])[:, None, None] * mods.scale[:, None, None]
                mu = np.where(inside, mpatch, mu)
            try:
                r = model.step(State(q, v), u, e0, e1, mu=np.asarray(mu), mu_surface=mus_arr)
                q, v = r.q, r.v
            except DbcSlamError:
                q = np.full_like(q, np.nan)
                v = np.full_like(v, np.nan)
            out[:, :, h] = q
        out = out + bias[:, None, None, :]
        return np.asarray(out, dtype=np.float64)

    def rollout(self, mods: Mods) -> list[F64]:
        """Residuals per run: obs - pred [G, S, H, nq] (yaw wrapped, nan where unusable)."""
        res = []
        for d in self.data:
            pred = self._rollout_run(d, mods)
            r = d.target[None] - pred
            if r.shape[-1] == 3:
                r[..., 2] = np.mod(r[..., 2] + np.pi, 2.0 * np.pi) - np.pi
            r[~np.isfinite(pred)] = 1.0  # failed or diverged prediction: a big residual
            res.append(r)
        return res

    def prediction(self, mods: Mods) -> Prediction:
        """Full predictions of one (unbatched) model for reports and plots."""
        preds, tg, rs, held, ri, ts, q0, v0, ic = [], [], [], [], [], [], [], [], []
        for i, d in enumerate(self.data):
            p = self._rollout_run(d, mods)[0]
            r = d.target - p
            if r.shape[-1] == 3:
                r[..., 2] = np.mod(r[..., 2] + np.pi, 2.0 * np.pi) - np.pi
            preds.append(p)
            tg.append(d.target)
            rs.append(r)
            held.append(d.held)
            ri.append(np.full(d.starts.size, i))
            ts.append(d.run.t[d.starts])
            q0.append(d.q0)
            v0.append(d.v0)
            env = d.run.env[d.starts]
            kin = contact_kinematics(d.run.scenario, d.q0, env)
            ic.append(np.any(kin.phi <= 1e-3, axis=-1))
        return Prediction(
            pred=np.concatenate(preds),
            target=np.concatenate(tg),
            resid=np.concatenate(rs),
            held=np.concatenate(held),
            run_index=np.concatenate(ri).astype(np.int64),
            t=np.concatenate(ts),
            q0=np.concatenate(q0),
            v0=np.concatenate(v0),
            in_contact=np.concatenate(ic),
            shape_resid=np.concatenate([r[0] for r in self.project([r[None] for r in rs])]),
        )

    def overlap_weight(self, held: bool) -> float:
        """Distinct observed samples / residual entries over the (held-out or training)
        rollouts: overlapping rollouts see each observation up to horizon / stride times,
        so summed log-likelihoods are scaled by this to count every observation once."""
        distinct = 0
        entries = 0
        hz = self.cfg.horizon
        for d, m in zip(self.data, self.split_mask(held), strict=True):
            st = d.starts[m]
            if st.size == 0:
                continue
            distinct += int(np.unique(st[:, None] + 1 + np.arange(hz)[None, :]).size)
            entries += int(st.size * hz)
        return distinct / entries if entries else 1.0

    def split_mask(self, held: bool) -> list[NDArray[np.bool_]]:
        return [d.held == held for d in self.data]


def mods_of(extensions: Sequence[ModelExtension]) -> Mods:
    """Predictor modifications equivalent to a list of extensions (G = 1)."""
    m = Mods.nominal(1)
    d = dict(m.__dict__)
    for e in extensions:
        p = dict(e.params)
        if e.effect == "mass_scale":
            d["mass"] = float(d["mass"]) * p["factor"]
        elif e.effect == "support_pressure":
            d["rim"] = p["rim_fraction"]
        elif e.effect == "sensor_bias":
            d["bias"] = np.array([[p["x"], p["y"], p["yaw"]]])
        elif e.effect == "friction_patch":
            d["patch"] = np.array([[p["x_min"], p["x_max"], p["mu"]]])
        elif e.effect == "friction_scale":
            d["scale"] = d["scale"] * p["factor"]
        elif e.effect == "viscous_damping":
            d["b"] = d["b"] + p["b"]
        elif e.effect == "input_gain":
            d["gain"] = d["gain"] * p["factor"]
        elif e.effect == "sensor_delay":
            d["delay"] = d["delay"] + p["seconds"]
        elif e.effect == "support_friction":
            d["mu_s"] = np.array([p["mu"]])
    return Mods(**d)


def _corr(a: F64, b: F64) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if np.sum(ok) < 3 or np.std(a[ok]) == 0 or np.std(b[ok]) == 0:
        return 0.0
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def characterise(p: Prediction, dt: float) -> dict[str, Any]:
    """Residual statistics of a prediction (all starts): bias, growth, correlations, lag."""
    r = p.resid
    hz = r.shape[1]
    pos = np.sqrt(np.nansum(r[..., :2] ** 2, axis=-1))  # (S, H)
    last = r[:, -1, :2]
    speed = np.linalg.norm(p.v0[:, :2], axis=-1)
    out: dict[str, Any] = {
        "bias_one_step": [round(float(x), 7) for x in np.nanmean(r[:, 0], axis=0)],
        "bias_horizon": [round(float(x), 7) for x in np.nanmean(r[:, -1], axis=0)],
        "rmse_by_horizon": [round(float(x), 7) for x in np.sqrt(np.nanmean(pos**2, axis=0))],
        "horizon_s": round(hz * dt, 4),
        "growth_per_s": round(
            float(
                (np.sqrt(np.nanmean(pos[:, -1] ** 2)) - np.sqrt(np.nanmean(pos[:, 0] ** 2)))
                / max((hz - 1) * dt, dt)
            ),
            6,
        ),
        "corr_velocity": {
            "rx_vx": round(_corr(last[:, 0], p.v0[:, 0]), 3),
            "ry_vy": round(_corr(last[:, 1], p.v0[:, 1]), 3),
            "abs_speed": round(_corr(np.linalg.norm(last, axis=-1), speed), 3),
        },
        "corr_position": {
            "rx_x": round(_corr(last[:, 0], p.q0[:, 0]), 3),
            "ry_y": round(_corr(last[:, 1], p.q0[:, 1]), 3),
        },
        "rmse_in_contact": round(float(np.sqrt(np.nanmean(pos[p.in_contact] ** 2))), 7)
        if np.any(p.in_contact)
        else None,
        "rmse_free": round(float(np.sqrt(np.nanmean(pos[~p.in_contact] ** 2))), 7)
        if np.any(~p.in_contact)
        else None,
    }
    # time lag: shift of the predicted one-step displacement that best matches the observed
    dq_obs = p.target[:, 0, :2] - p.q0[:, :2]
    dq_pred = p.pred[:, 0, :2] - p.q0[:, :2]
    best, best_c = 0, -2.0
    for lag in range(-5, 6):
        a = np.roll(dq_pred, lag, axis=0)
        c = _corr(a.reshape(-1), dq_obs.reshape(-1))
        if c > best_c:
            best, best_c = lag, c
    out["best_lag_starts"] = best
    return out
