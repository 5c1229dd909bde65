"""A model on the data: its parameter vector, the gyro reading it predicts, its residual and score.

Layout places the inertia, each effect's parameters and each segment's initial rates in one
vector x; predict integrates the model (model.simulate) to the gyro reading at every sample;
whitened and objective give the least-squares vector the solver minimises, jacobian its
finite-difference columns; finish scores an x as a Fit (its residuals and BIC).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from inertia_gym.discrepancy.data import Data
from inertia_gym.discrepancy.effects import REGISTRY, EffectModel
from inertia_gym.discrepancy.model import OwnTerms, effect_terms, gyro_output, simulate
from inertia_gym.estimation.inertia_param import PHI_BOUND, inertia_from_phi, realizable_face, realizable_phi

# ------------------------------------------------------------------------------------------
# Models: the parameter layout and the prediction of the gyro reading
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Layout:
    """x = [phi (6), p_1, ..., p_k, w0 (S, 3)]: the inertia (log-Cholesky, its trace pinned to
    d.trace0 when d.scale_fixed; not used when the sidecar's nominal is held), each effect's
    vector in its form, each segment's initial rates.
    """

    names: tuple[str, ...]
    forms: tuple[str, ...]
    sizes: tuple[int, ...]
    segments: int
    omega_max: float = 0.0  # rad/s: the fastest a flexible mode may be in this fit (its grid)

    @classmethod
    def of(cls, names, forms, d: Data, omega_max: float = 0.0) -> "Layout":
        """Layout of the effects `names` in `forms` on d."""
        return cls(tuple(names), tuple(forms),
                   tuple(REGISTRY[n].form_size(f, d) for n, f in zip(names, forms)), d.segments,
                   float(omega_max))

    @functools.cached_property
    def models(self) -> list[EffectModel]:
        """The effects' registered models (cached: every evaluation of the model asks them)."""
        return [REGISTRY[n] for n in self.names]

    @functools.cached_property
    def reads_through(self) -> bool:
        """Some effect changes what the gyro reads of the rates (EffectModel.gyro)."""
        return any(type(m).gyro is not EffectModel.gyro for m in self.models)

    @functools.cached_property
    def has_penalty(self) -> bool:
        """Some effect has constraint rows (EffectModel.penalty)."""
        return any(type(m).penalty is not EffectModel.penalty for m in self.models)

    @property
    def n_global(self) -> int:
        """Inertia and effect parameters."""
        return 6 + sum(self.sizes)

    @property
    def size(self) -> int:
        """Length of x."""
        return self.n_global + 3 * self.segments

    def slices(self) -> list[slice]:
        """Each effect's slice of x."""
        return self._slices

    @functools.cached_property
    def _slices(self) -> list[slice]:
        out, i = [], 6
        for s in self.sizes:
            out.append(slice(i, i + s))
            i += s
        return out

    def parts(self, x, d: "Data") -> list[tuple[EffectModel, dict]]:
        """[(model, named params)] of x; an inertia an effect sets has its trace pinned to
        d.trace0 where the scale is not seen.
        """
        return [(m, named_params(m, x[s], d)) for m, s in zip(self.models, self.slices())]

    def feasible(self, x, d: Data) -> np.ndarray:
        """The joint vector x with a fitted base inertia projected onto the inertias a body can
        have (inertia_param.realizable_phi: each principal moment at most the sum of the other
        two), and each effect's part onto what its physics allows with the model's inertia at x
        (EffectModel.feasible).
        """
        x = np.array(x, float)
        if d.inertia0 is None and not any(m.sets_inertia for m in self.models):
            x[:6] = realizable_phi(x[:6])  # the fitted inertia: only bodies that exist
        inertia = model_inertia(self, x, d)
        for m, s in zip(self.models, self.slices()):
            x[s] = m.feasible(x[s], inertia)
        return x

    def face(self, x) -> np.ndarray:
        """(m, n_global) rows of every effect's face (EffectModel.face) at x, in x's columns, and
        of the inertias' limit (realizable_face of phi = x[:6]; its rows fall outside the free
        columns where the nominal inertia is held).
        """
        limit = realizable_face(np.asarray(x[:6], float))
        rows = [np.zeros((0, self.n_global)), np.pad(limit, ((0, 0), (0, self.n_global - 6)))]
        for m, s in zip(self.models, self.slices()):
            a = m.face(np.asarray(x[s], float))
            if a.size:
                full = np.zeros((a.shape[0], self.n_global))
                full[:, s] = a
                rows.append(full)
        return np.vstack(rows)


def named_params(model: EffectModel, p, d: "Data") -> dict:
    """Model's named parameters at its part p of a joint vector: its unpack, with an inertia it
    sets pinned to d.trace0 where the scale is not seen (_pinned).
    """
    params = model.unpack(np.asarray(p, float))
    if model.sets_inertia and d.scale_fixed:
        params = {**params, "inertia": _pinned(params["inertia"], d)}
    return params


def _pinned(j, d: Data) -> np.ndarray:
    """Inertia j scaled to trace d.trace0."""
    j = np.asarray(j, float)
    return j * (d.trace0 / np.trace(j))


def base_inertia(x, d: Data) -> np.ndarray:
    """The inertia (3, 3) kg·m² of every model but inertia_offset: the sidecar's nominal where
    given, else phi = x[:6] (its trace pinned to d.trace0 when the scale is not seen).
    """
    if d.inertia0 is not None:
        return d.inertia0
    j = inertia_from_phi(np.asarray(x[:6], float))
    return _pinned(j, d) if d.scale_fixed else j


def model_inertia(layout: Layout, x, d: Data) -> np.ndarray:
    """The model's inertia (3, 3) kg·m²: an effect's (inertia_offset) where one sets it."""
    for model, s in zip(layout.models, layout.slices()):
        if model.sets_inertia:  # (only such an effect has a true_inertia)
            j = model.true_inertia(named_params(model, x[s], d))
            if j is not None:
                return np.asarray(j, float)
    return base_inertia(x, d)


def predict(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, n, 3) rad/s: the gyro reading the model predicts at every sample, for x in xs (B, size)."""
    grid = d.grid_for(layout.omega_max if "flexible_mode" in layout.names else 0.0)
    cumulative, commanded, h_known = d.inputs(grid)
    seg_pos = np.append(grid.sample_pos[d.seg[:-1]], grid.steps)
    xs = np.asarray(xs, float)
    q0 = d.q0()
    # the segments' rates are not in the model, and the effects' terms do not depend on the
    # inertia (a Jacobian's inertia columns share them): each built once
    effect_keys = [x[6:layout.n_global].tobytes() for x in xs]
    motion = d.motion(grid) if "flight" in layout.forms else None  # what a flight's air reads
    effects: dict = {}  # effect key -> (its parts, EffectTerms, the indices of xs that have it)
    built: dict = {}  # the whole model's key -> its Terms
    inertias: dict = {}  # x[:6]'s bytes -> base_inertia: the columns of the effects share it
    terms = []
    own: dict = {}  # (effect index, its part of x's bytes) -> its named params and OwnTerms
    for i, (effect_key, x) in enumerate(zip(effect_keys, xs)):
        if effect_key not in effects:
            # a column of one effect's parameter leaves the others' terms as they are
            parts = []
            for j, (m, s) in enumerate(zip(layout.models, layout.slices())):
                part_key = (j, x[s].tobytes())
                if part_key not in own:
                    params = named_params(m, x[s], d)
                    own[part_key] = params, OwnTerms.of(m, params, grid, motion)
                parts.append(own[part_key])
            p = [(m, params) for m, (params, _) in zip(layout.models, parts)]
            effects[effect_key] = (p, effect_terms(p, grid, cumulative, h_known, commanded, motion,
                                                   [o for _, o in parts]), [])
        p, shared, members = effects[effect_key]
        members.append(i)
        phi_key = x[:6].tobytes()
        key = phi_key + effect_key
        if key not in built:
            if phi_key not in inertias:
                inertias[phi_key] = base_inertia(x, d)
            built[key] = shared.on(inertias[phi_key])
        terms.append(built[key])
    w0 = xs[:, layout.n_global:].reshape(len(xs), -1, 3)
    y0 = np.concatenate([np.broadcast_to(q0, (len(xs), *q0.shape)), w0], axis=2)
    out = simulate(grid, seg_pos, y0, terms)[..., 4:]
    if layout.reads_through:  # the sensor's terms, applied to every trajectory of a model at once
        for p, _, members in effects.values():
            out[members] = gyro_output(p, out[members], d.t)
    return out


def _row_means(d: Data, values) -> np.ndarray:
    """(..., n, 3) per-sample values -> (..., n_rows, 3) their means over each row's samples
    (values itself where every sample is a row of its own).
    """
    if d.cache.get("rows", (None,))[0] is not d.row:  # (resegmented data share the cache)
        idx = np.flatnonzero(d.row >= 0)
        starts = np.flatnonzero(np.r_[True, np.diff(d.row[idx]) != 0])
        d.cache["rows"] = (d.row, None if idx.size == d.row.size else idx,
                           None if starts.size == idx.size else starts,
                           np.bincount(d.row[idx])[:, None])
    _, idx, starts, counts = d.cache["rows"]
    kept = values if idx is None else values[..., idx, :]
    if starts is None:  # a sample a row: the rows are the kept samples
        return kept
    return np.add.reduceat(kept, starts, axis=-2) / counts


def whitened(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, n_rows, 3) residual rows (predicted - measured) in units of their noise; a model that
    blew up gives non-finite rows, silently (objective and finish price them).
    """
    # (data replaced with another noise level or other rows share the cache: both are checked)
    held = d.cache.get("row_weight", (None, None, None))
    if held[0] is not d.row_scale or held[1] is not d.sigma:
        held = d.cache["row_weight"] = (d.row_scale, d.sigma, d.sigma * d.row_scale[:, None])
    with np.errstate(over="ignore", invalid="ignore"):
        rows = _row_means(d, np.subtract(predict(xs, layout, d), d.w))
        rows /= held[2]
        return rows


def _penalty_rows(x, layout: Layout, d: Data, n_res: int) -> np.ndarray:
    """The effects' constraint rows (EffectModel.penalty), weighted 1e3 sqrt(N)."""
    rows = []
    for model, s in zip(layout.models, layout.slices()):
        rows += model.penalty(np.asarray(x[s], float), d)
    return 1e3 * np.sqrt(n_res) * np.asarray(rows, float)


def objective(xs, layout: Layout, d: Data) -> np.ndarray:
    """(B, N) the least-squares vector: whitened residual rows, then any constraint rows."""
    z = whitened(xs, layout, d).reshape(len(xs), -1)
    # a model that blew up costs a lot, finitely: inf is clipped, nan priced at the clip
    np.clip(z, -1e6, 1e6, out=z)
    z[np.isnan(z)] = 1e6
    if not layout.has_penalty:
        return z
    pen = [_penalty_rows(x, layout, d, z.shape[1]) for x in xs]
    return np.hstack([z, np.stack(pen)]) if pen[0].size else z


def _steps(x, layout: Layout, d: Data) -> np.ndarray:
    """Finite-difference steps of every x entry: 1e-6 of its size or of its typical size."""
    typical = [np.ones(6)] + [m.typical(f, d) for m, f in zip(layout.models, layout.forms)]
    typical.append(np.full(3 * layout.segments, d.omega_ref))
    return 1e-6 * np.maximum(np.abs(x), np.concatenate(typical))


def jacobian(x, free, layout: Layout, d: Data, central: bool = False, r0=None):
    """Objective r0 (N,), its columns for the free global entries G (N, P) and for the segment
    rates Js (N, 3) (entry i's derivative with respect to the rates of its own segment).

    All columns come from one batched integration: one trajectory per free global entry and
    three for the rates of all segments at once (forward differences; central with central=True).
    r0: the objective at x where already known (it is then not integrated again).
    """
    points = _jacobian_points(x, free, layout, d, central)
    if r0 is None:
        r = objective(np.vstack([x[None], points]), layout, d)
        return _jacobian_columns(x, free, layout, d, r[0], r[1:], central)
    return _jacobian_columns(x, free, layout, d, r0, objective(points, layout, d), central)


def _jacobian_points(x, free, layout: Layout, d: Data, central: bool) -> np.ndarray:
    """(P + 3, size) the points jacobian() integrates besides x (2 (P + 3) with central): x with
    each free global entry moved by its step, then with every segment's rates moved along each
    axis (then the same moved the other way).
    """
    gi = np.flatnonzero(free[:layout.n_global])
    h = _steps(x, layout, d)
    plus = np.repeat(x[None], gi.size + 3, axis=0)
    plus[np.arange(gi.size), gi] += h[gi]
    seg_h = h[layout.n_global:].reshape(-1, 3)
    for c in range(3):
        plus[gi.size + c, layout.n_global + c::3] += seg_h[:, c]
    return np.vstack([plus, 2 * x - plus]) if central else plus


def _jacobian_columns(x, free, layout: Layout, d: Data, r0, rs, central: bool):
    """jacobian()'s (r0, G, Js) from the objective r0 (N,) at x and rs at its _jacobian_points."""
    gi = np.flatnonzero(free[:layout.n_global])
    h = _steps(x, layout, d)
    seg_h = h[layout.n_global:].reshape(-1, 3)
    n_plus = gi.size + 3
    hp = np.r_[h[gi], seg_h.mean(axis=0)]
    if central:
        cols = (rs[:n_plus] - rs[n_plus:]) / (2 * hp[:, None])
    else:
        cols = (rs - r0) / hp[:, None]
    # the rate columns: each entry's own segment's step (segments' steps differ)
    n_res = d.n_rows * 3
    seg_of = np.repeat(d.row_seg, 3)
    js = np.zeros((r0.size, 3))
    for c in range(3):
        js[:n_res, c] = cols[gi.size + c][:n_res] * hp[gi.size + c] / seg_h[seg_of, c]
    return r0, cols[:gi.size].T, js


# ------------------------------------------------------------------------------------------
# Fits
# ------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Fit:
    """One fitted model: its layout, x, the whitened residual rows z (n_rows, 3), the rate
    residual rows r (n_rows, 3) rad/s, bic, k (free global parameters), inertia (3, 3) kg·m²,
    and each effect's named parameters.
    """

    layout: Layout
    x: np.ndarray
    z: np.ndarray
    r: np.ndarray
    bic: float
    k: int
    inertia: np.ndarray
    effect_params: dict  # effect name -> its named parameters, in the order the effects were added

    @property
    def names(self) -> tuple[str, ...]:
        """Its effects (() = the nominal model)."""
        return self.layout.names

    @property
    def name(self) -> str | None:
        """The last effect added (the only one of a single-effect fit), None for the nominal."""
        return self.names[-1] if self.names else None

    @property
    def forms(self) -> tuple[str, ...]:
        """The form of each effect."""
        return self.layout.forms

    @property
    def params(self) -> dict:
        """The last effect's named parameters ({} for the nominal)."""
        return self.effect_params[self.name] if self.names else {}


def _free(layout: Layout, d: Data) -> np.ndarray:
    """Bool mask over x of what the solver moves."""
    sets = any(m.sets_inertia for m in layout.models)
    phi = np.full(6, not sets and d.inertia0 is None)
    phi[0] &= not d.scale_fixed
    held = [~m.held(f, d) for m, f in zip(layout.models, layout.forms)]
    return np.concatenate([phi] + held + [np.ones(3 * layout.segments, bool)])


def _bounds(layout: Layout, d: Data):
    lo, hi = [-PHI_BOUND], [PHI_BOUND]
    for m, f in zip(layout.models, layout.forms):
        a, b = m.bounds(f, d)
        lo.append(a)
        hi.append(b)
    if "flexible_mode" in layout.names:  # the mode stays on the grid this fit integrates on
        hi[1 + layout.names.index("flexible_mode")][0] = layout.omega_max
    tail = np.full(3 * layout.segments, np.inf)
    return np.concatenate(lo + [-tail]), np.concatenate(hi + [tail])


def finish(layout: Layout, x, d: Data, k: int | None = None) -> Fit:
    """The Fit of x: residuals and BIC (k: free global parameters, counted from layout if None)."""
    if k is None:
        k = int(_free(layout, d)[:layout.n_global].sum())
    z = whitened(np.asarray(x, float)[None], layout, d)[0]
    jm = model_inertia(layout, x, d)
    n = z.size * d.effective_share
    with np.errstate(over="ignore"):
        mse = float(np.mean(z ** 2)) if np.all(np.isfinite(z)) else np.inf
    bic = n * np.log(max(mse, 1e-300)) + k * np.log(n) if np.isfinite(mse) else np.inf
    named = {m.name: params for m, params in layout.parts(x, d)}
    return Fit(layout, np.asarray(x, float), z, z * d.sigma * d.row_scale[:, None], float(bic), k, jm, named)
