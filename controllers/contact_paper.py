"""The paper's distributed-force identification as we read it, and plain weighted least
squares: the two estimators the daemon's own (controllers.contact_force) is compared with
(rig-facts §3; the model and region in controllers.contact_model).

:class:`PaperSWLS`, the paper's nested layers, one frame at a time:

**Inner, spatial layer**: the neighbouring-response region; its geometry (cx, cy, a, b)
tracked from frame to frame by recursive Gauss-Newton on the pressure model over the region
and its ring of untouched neighbours (whose zeros pin the edge), [ln p_max, beta] taken as
the last frame's: each frame's normal equations join the last ones' with forgetting 0.6
(:class:`GeometryTracker`); at first touch a quadric fit starts it (**interpretation**: the
paper's geometry step is not legible); then the log transform, ln p = ln p_max + beta ln phi,
over the touched taxels, each weighted by a sigmoid in phi that lets taxels near the
contact's edge (where ln phi amplifies the noise without bound) count little (S-WLS). Over a
sensing area ln phi becomes g = d ln mean(phi^beta) / d beta at the last beta, exact at the
fixed point (:func:`log_rows`).

**Outer, temporal layer**: recursive least squares on theta = [ln p_max, beta] in
information form with forgetting factor lambda per frame, each taxel's row entering with its
sigmoid weight times (p / p_peak)^2, the inverse of ln p's variance (the per-sample weight):
R <- lambda R + sum w h h^T, r <- lambda r + sum w h z, theta = R^-1 r; p_max = exp(theta_1),
beta = theta_2, fed back to the next frame's geometry. A frame with no contact resets it.

Its memories hold constant parameters, so they lag a contact that grows or shrinks; the
geometry and beta are estimated apart, so beta inherits two to three times any geometry
error through ln phi. Both are why the daemon's estimator is another (docs/estimation.md).

:class:`PlainWLS`, the baseline: the same region; in each frame alone the geometry (one
Gauss-Newton step of all six parameters) and [ln p_max, beta] by plain weighted least squares
(weights the taxel pressures; no sigmoid, no memory).
"""
from __future__ import annotations

import math

import numpy as np

from controllers.contact_model import (
    MM,
    THRESHOLD_PA,
    ContactEstimate,
    SensingGrid,
    contact_region,
    dilate,
    model_jacobian,
    quadric_geometry,
)

GEOMETRY_FORGETTING = 0.6  # the geometry's memory per frame (0: each frame alone); chosen on simulated impacts


class GeometryTracker:
    """The contact's geometry (cx, cy, a, b [mm]) tracked from frame to frame by recursive
    Gauss-Newton on the pressure model, [ln p_max, beta] taken as the last frame's: each
    frame's normal equations J^T J join the last ones' with forgetting ``forgetting`` (a memory
    of about 1 / (1 - forgetting) frames), and one step is taken on this frame's residual.
    A frame alone gives a and b to 1-5 % on a contact 2 taxels across (sensor noise), and beta
    inherits two to three times a geometry error through ln phi; the memory averages it.

    ``joint``: ln p_max and beta stepped with the geometry (the baseline's geometry, with
    forgetting 0: each frame alone; plain WLS's per-frame beta fed to a geometry memory runs
    away)."""

    def __init__(self, forgetting: float, joint: bool = False):
        self.forgetting = forgetting
        self.columns = 6 if joint else 4
        self.reset()

    def reset(self) -> None:
        self.normal = np.zeros((self.columns, self.columns))

    def step(self, shape: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, damping: float = 1e-3):
        """The new geometry for the state ``shape`` and the pressures p [Pa] at sensing points
        (x, y) [mm], and the model's relative RMS residual before the step; None if the step
        leaves the model's domain."""
        model, jac = model_jacobian(shape, x, y)
        jac = jac[:, :self.columns]
        error = p - model
        self.normal = self.forgetting * self.normal + jac.T @ jac
        damped = self.normal.copy()
        damped[np.diag_indices(self.columns)] *= 1.0 + damping
        new = shape[:self.columns] + np.linalg.solve(damped, jac.T @ error)
        if not np.all(np.isfinite(new)) or new[2] <= 0.1 or new[3] <= 0.1:
            return None
        return new[:4], math.sqrt(float(error @ error) / float(p @ p))


def log_rows(shape: np.ndarray, px: np.ndarray, py: np.ndarray, p: np.ndarray):
    """The log transform's rows for the taxels the contact touches: z = ln p against
    h = [1, g]. For a taxel sensing at one point g = ln phi and z = ln p (rig-facts §3); over
    a sensing area g = d ln mean(phi^beta) / d beta at the last beta and z carries the rest
    of ln mean(phi^beta). Also each taxel's effective phi (mean(phi^beta)^(1/beta)) for the
    sigmoid weight, and its pressure; None when fewer than 3 taxels are touched."""
    cx, cy, a, b, _, beta = shape
    phi = 1.0 - ((px - cx) / a) ** 2 - ((py - cy) / b) ** 2
    touched = (p > THRESHOLD_PA) & (phi.max(axis=1) > 0)
    if np.count_nonzero(touched) < 3:
        return None
    phi, p = phi[touched], p[touched]
    inside = phi > 1e-9
    phi = np.where(inside, phi, 1.0)
    powered = np.where(inside, phi ** beta, 0.0)
    mean = powered.sum(axis=1) / phi.shape[1]
    g = (powered * np.log(phi)).sum(axis=1) / (phi.shape[1] * mean)
    z = np.log(p) - (np.log(mean) - beta * g)
    return np.column_stack([np.ones_like(g), g]), z, mean ** (1.0 / beta), p


def sigmoid_weight(phi: np.ndarray, centre: float = 0.5, width: float = 0.06) -> np.ndarray:
    """The S-WLS weight: near 0 over the contact's outer half in phi (where ln phi amplifies the
    geometry's error and the noise), near 1 inside. The centre was chosen on simulated impacts
    (0.2 to 0.7 tried: beta's largest error fell from 6.3 to 5.0 % going from 0.2 to 0.5, and
    rose again beyond; tried again, 0.3-0.7 and widths 0.03-0.1, with the geometry's memory:
    0.5 and 0.06 kept)."""
    return 1.0 / (1.0 + np.exp(-(phi - centre) / width))


class _Layers:
    """What both estimators share: frame -> region -> geometry (tracked from frame to frame)
    -> the log layer's rows for [ln p_max, beta]; a subclass solves those rows."""

    def __init__(self, geometry: GeometryTracker):
        self.geometry = geometry
        self.grid = SensingGrid()
        self.reset()

    def reset(self) -> None:
        self.shape = None  # (cx, cy, a, b) [mm], ln p_max, beta: the state from frame to frame
        self.geometry.reset()

    def update(self, frame_pa: np.ndarray, frames: int = 1) -> ContactEstimate | None:
        """One frame [Pa] (16 x 16, NaN where dead) -> the contact, or None (no contact).
        ``frames``: frame periods since the last call (its memories hold constant parameters,
        so a gap changes nothing)."""
        region = contact_region(frame_pa)
        if region is None:
            self.reset()
            return None
        ring = dilate(region) & ~np.isnan(frame_pa)
        p = frame_pa[ring]
        if self.shape is None:
            first = quadric_geometry(self.grid.x[region], self.grid.y[region], frame_pa[region])
            if first is None:
                return None
            self.shape = np.array([*first, math.log(float(frame_pa[region].max())), 0.5])
        px, py = self.grid.px[ring], self.grid.py[ring]
        stepped = self.geometry.step(self.shape, px, py, p)
        shape = np.concatenate([stepped[0], self.shape[4:]]) if stepped is not None else None
        rows = log_rows(shape, px, py, p) if shape is not None else None
        theta = self._solve(*rows) if rows is not None else None
        if theta is None or not np.all(np.isfinite(theta)) or not 0.05 <= theta[1] <= 5.0:
            self.reset()  # no cap shape: the model does not hold this frame
            return None
        shape[4:] = theta
        self.shape, residual = shape, stepped[1]
        cx, cy, a, b, ln_pmax, beta = shape
        return ContactEstimate(cx / MM, cy / MM, a / MM, b / MM, math.exp(ln_pmax), beta, len(p), residual)

    def _solve(self, h: np.ndarray, z: np.ndarray, phi: np.ndarray, p: np.ndarray):
        raise NotImplementedError


class PaperSWLS(_Layers):
    """The paper's method: S-WLS rows in a frame, recursive least squares across frames."""

    def __init__(self, forgetting: float = 0.8, geometry_forgetting: float = GEOMETRY_FORGETTING):
        if not 0.0 < forgetting <= 1.0:
            raise ValueError(f"forgetting factor {forgetting}: 0 < lambda <= 1")
        if not 0.0 <= geometry_forgetting < 1.0:
            raise ValueError(f"geometry forgetting factor {geometry_forgetting}: 0 <= lambda < 1")
        self.forgetting = forgetting
        super().__init__(GeometryTracker(geometry_forgetting))

    def reset(self) -> None:
        super().reset()
        self.info = np.zeros((2, 2))
        self.moment = np.zeros(2)

    def _solve(self, h, z, phi, p):
        """Each row's weight: the sigmoid in phi, times (p / p_peak)^2, the inverse of ln p's
        variance under the sensor's even noise (var ln p = (sigma / p)^2): the paper's per-sample
        weight, read so."""
        hw = h * (sigmoid_weight(phi) * (p / p.max()) ** 2)[:, None]
        self.info = self.forgetting * self.info + hw.T @ h
        self.moment = self.forgetting * self.moment + hw.T @ z
        (r11, r12), (_, r22) = self.info
        det = r11 * r22 - r12 * r12
        if not det > 1e-12 * r11 * r22:
            return None
        m1, m2 = self.moment
        return np.array([(r22 * m1 - r12 * m2) / det, (r11 * m2 - r12 * m1) / det])


class PlainWLS(_Layers):
    """The baseline: the same region, and in each frame alone its geometry (stepped jointly with
    ln p_max and beta) and [ln p_max, beta] by weighted least squares, the taxel pressures as
    weights."""

    def __init__(self):
        super().__init__(GeometryTracker(0.0, joint=True))

    def _solve(self, h, z, phi, p):
        sw = np.sqrt(p)
        return np.linalg.lstsq(h * sw[:, None], z * sw, rcond=None)[0]
