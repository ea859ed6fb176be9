"""The GP-AKF's residual hook compiled in one call (:class:`~sea_daemon.core.estimators.gpakf._ResidualHook`).

With learning frozen, the hook's prediction — the GP input clipped into the training box, per
joint the merged LoG-GP mean, its Jacobian and variance (:meth:`LoGGP.predict_grad_into`:
routing, each leaf's compiled prediction, the merge in routing order) — runs as one compiled
call, :func:`hook_predict`, over the LoG-GPs flattened by
:class:`~sea_daemon.core.gp.pack.GPPack` (the pack the Theorem-1 bound uses), with the
same operations in the same order.  A GP that is learning stays on the Python path.
"""
from __future__ import annotations

import numpy as np

from sea_daemon.core.jit import njit, warmer
from sea_daemon.core.gp.pack import GPPack, warm_up_loggp
from sea_daemon.core.gp import gp_core
from sea_daemon.core.gp.routing import route
from sea_daemon.core.estimators.health import box_clip


@njit
def _leaf_grad(l, x, nn, row, apo, A, beta, alpha, ap, center, il2, sf2, lo, hi, clip, xc, dmu, dvar):
    """(μ, σ²) of leaf l at x with ∂μ/∂x into ``dmu``: IncrementalGP.predict_with_grad (with
    clip_mean: μ and ∂μ/∂x at the clipped input, 0 in the clipped coordinates, σ² at x)."""
    m = nn[l]
    if m == 0:
        dmu[:] = 0.0
        return 0.0, sf2[l]
    r0, p0 = row[l], apo[l]
    Al = A[r0:r0 + m]
    apl = ap[p0:p0 + m * (m + 1) // 2]
    bl = beta[r0:r0 + m]
    al = alpha[r0:r0 + m]
    if clip[l] and gp_core.clip_into(x, lo[l], hi[l], xc):
        var = gp_core.predict(Al, apl, bl, center[l], il2[l], m, sf2[l], x)[1]
        mu, _ = gp_core.predict_with_grad(Al, apl, bl, al, True, center[l], il2[l], m, sf2[l], xc, False, dmu,
                                          dmu)
        for i in range(x.shape[0]):
            if xc[i] != x[i]:
                dmu[i] = 0.0
        return mu, var
    return gp_core.predict_with_grad(Al, apl, bl, al, True, center[l], il2[l], m, sf2[l], x, False, dmu, dvar)


@njit
def hook_predict(z, box_lo, box_hi, zc, clipped, noise, mu_out, jac, var_out, links, span, leaf_of, nn, row, apo,
                 A, X, beta, alpha, ap, center, il2, sf2, lo, hi, clip, r, sn2):
    """The GP-AKF's residual hook in one call (gpakf._ResidualHook.predict over frozen LoG-GPs):
    z clipped into the input box (``zc``, ``clipped``; health.box_clip), per joint j the merged
    LoG-GP μ_j, ∂μ_j/∂z (row j of ``jac``) and σ_j² (+ Σ ω σ_on² with ``noise``) at the clipped
    input, as LoGGP.predict_grad_into with ``weights_grad=False`` (the experts' Jacobian), the
    same operations in the same order; the clipped coordinates get a zero Jacobian.  Returns whether any coordinate was clipped."""
    any_clipped = box_clip(z, box_lo, box_hi, zc, clipped)
    d = zc.shape[0]
    Zr = zc.reshape((1, d))
    dm = np.empty(d)
    dv = np.empty(d)
    xc = np.empty(d)
    acc = np.empty(d)
    for j in range(links.shape[0]):
        _, nodes, ws, _ = route(Zr, links[j], span[j], False)
        k = nodes.shape[0]
        if k == 1:
            mu, var = _leaf_grad(leaf_of[j, nodes[0]], zc, nn, row, apo, A, beta, alpha, ap, center, il2, sf2, lo,
                                 hi, clip, xc, jac[j], dv)
        else:
            mu = m2 = 0.0
            acc[:] = 0.0
            for i in range(k):
                w = ws[i]
                m, v = _leaf_grad(leaf_of[j, nodes[i]], zc, nn, row, apo, A, beta, alpha, ap, center, il2, sf2, lo,
                                  hi, clip, xc, dm, dv)
                mu += w * m
                m2 += w * (v + m * m)
                # the experts' Jacobian Σ ω_i ∂μ_i (eq:moejac per leaf), without the routing
                # ramp's μ_i ∂ω_i: the experts' disagreement is in σ² (Q), not in F
                for c in range(d):
                    acc[c] += w * dm[c]
            var = m2 - mu * mu
            if var < 0.0:
                var = 0.0
            for c in range(d):
                jac[j, c] = acc[c]
        if noise:
            sn = 0.0
            for i in range(k):
                sn += ws[i] * sn2[leaf_of[j, nodes[i]]]
            var += sn
        mu_out[j] = mu
        var_out[j] = var
    if any_clipped:
        for j in range(jac.shape[0]):
            for c in range(d):
                if clipped[c]:
                    jac[j, c] = 0.0
    return any_clipped


@warmer
def _warm() -> None:
    """:func:`hook_predict` with the argument types the hook passes (one joint, z of 3)."""
    pack = GPPack([warm_up_loggp()])
    for noise in (False, True):
        hook_predict(np.zeros(3), -np.ones(3), np.ones(3), np.zeros(3), np.zeros(3, np.bool_), noise, np.zeros(1),
                     np.zeros((1, 3)), np.zeros(1), *pack.args(), pack.sn2)
