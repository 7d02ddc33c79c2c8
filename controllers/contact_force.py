"""Distributed-force identification from the array pressure sensor (rig-facts §3): the
contact region and the pressure on it, a frame at a time, with the paper's nested layers.

Contact model: an ellipse with centre (cx, cy) and semi-axes a, b [m] along the pad's x and
y (**interpretation**: the paper names no orientation; the pad's axes are taken), and

    p = p_max phi^beta,   phi = 1 - (x - cx)^2/a^2 - (y - cy)^2/b^2   (0 outside)      [Pa]

A taxel reports the mean pressure over its sensing area (about 1.9 mm^2, 1.38 mm square;
:func:`hal.taxel_array.sensing_offsets_m`), which matters at the edge of a contact a few
taxels across: the model is evaluated at 3 x 3 points over each taxel's area and averaged.

**Inner, spatial layer** (each frame):

1. the neighbouring-response region: dead taxels (NaN) take their live neighbours' mean;
   taxels above ``THRESHOLD_PA`` (twice the sensor's +-0.5 % FS, so noise alone never
   qualifies) are active; the region is the 8-connected group of active taxels grown from
   the frame's peak (other groups, a second touch or a hot taxel, are left out);
2. its geometry (cx, cy, a, b), tracked from frame to frame by recursive Gauss-Newton on the
   pressure-domain model over the region and its ring of untouched neighbours (whose zeros
   pin the edge), [ln p_max, beta] taken as the last frame's: each frame's normal equations
   join the last ones' with forgetting 0.6 (:class:`GeometryTracker`), so a small contact's
   geometry is not one frame's noise (beta inherits two to three times a geometry error);
   at first touch a quadric fit starts it: with beta = 0.5, p^(1/beta) is a quadric in x and
   y, linear in its coefficients (**interpretation**: the paper's geometry step is not
   legible; the taxels' coarse outline alone gives a, b only to a taxel, 2.5 mm, 20-40 % of a
   small contact, and the geometry's memory is ours);
3. the log transform, ln p = ln p_max + beta ln phi, over the touched taxels, for
   [ln p_max, beta], each taxel weighted by a sigmoid in phi that lets taxels near the
   contact's edge (where ln phi amplifies the noise without bound) count little (S-WLS).
   Over a sensing area ln phi becomes g = d ln mean(phi^beta) / d beta at the last beta,
   exact at the fixed point (:func:`log_rows`).

**Outer, temporal layer**: recursive least squares on theta = [ln p_max, beta] in
information form with forgetting factor lambda per frame, each taxel's row entering with its
sigmoid weight times (p / p_peak)^2, the inverse of ln p's variance (the per-sample weight):
R <- lambda R + sum w h h^T, r <- lambda r + sum w h z, theta = R^-1 r; p_max = exp(theta_1),
beta = theta_2, fed back to the next frame's geometry. A frame with no
contact resets it.

The baseline (:class:`PlainWLS`): the same region; in each frame alone the geometry (one
Gauss-Newton step of all six parameters) and [ln p_max, beta] by plain weighted least squares
(weights the taxel pressures; no sigmoid, no memory).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from hal.taxel_array import ACCURACY_PA, Contact, sensing_offsets_m, taxel_centres_m

THRESHOLD_PA = 2.0 * ACCURACY_PA
MIN_TAXELS = 8  # the quadric has 5 coefficients: fewer active taxels give no estimate
EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)
MM = 1e3  # the fits run in mm, so their columns are of like size
GEOMETRY_FORGETTING = 0.6  # the geometry's memory per frame (0: each frame alone); chosen on simulated impacts


@dataclass(frozen=True)
class ContactEstimate(Contact):
    """An identified contact, with the taxels the fit used and the model's relative RMS
    residual over them before this frame's step (0: it explains every taxel)."""

    taxels: int = 0
    residual: float = 0.0

    def as_dict(self) -> dict:
        return {**{k: float(v) if k != "taxels" else int(v) for k, v in vars(self).items()},
                "force_n": self.force_n, "area_m2": self.area_m2}


def contact_region(frame_pa: np.ndarray) -> np.ndarray | None:
    """The neighbouring-response region (a boolean mask), or None when nothing is touching."""
    dead = np.isnan(frame_pa)
    p = _fill_dead(frame_pa, dead) if dead.any() else frame_pa
    active = p > THRESHOLD_PA
    if np.count_nonzero(active) < MIN_TAXELS:
        return None
    labels, _ = ndimage.label(active, structure=EIGHT_CONNECTED)
    region = labels == labels.flat[np.argmax(np.where(active, p, -np.inf))]
    region &= ~dead  # a dead taxel joins the region's outline, never its data
    return region if np.count_nonzero(region) >= MIN_TAXELS else None


def _fill_dead(frame_pa: np.ndarray, dead: np.ndarray) -> np.ndarray:
    """Each dead taxel as the mean of its live 4-neighbours (0 if it has none)."""
    p = frame_pa.copy()
    rows, cols = frame_pa.shape
    for r, c in zip(*np.nonzero(dead)):
        around = [frame_pa[i, j] for i, j in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1))
                  if 0 <= i < rows and 0 <= j < cols and not dead[i, j]]
        p[r, c] = sum(around) / len(around) if around else 0.0
    return p


def dilate(mask: np.ndarray) -> np.ndarray:
    """The mask grown by one taxel in the 8 directions (its ring of neighbours added)."""
    grown = mask.copy()
    grown[1:, :] |= mask[:-1, :]
    grown[:-1, :] |= mask[1:, :]
    rows = grown.copy()
    grown[:, 1:] |= rows[:, :-1]
    grown[:, :-1] |= rows[:, 1:]
    return grown


def quadric_geometry(x: np.ndarray, y: np.ndarray, p: np.ndarray, beta: float = 0.5):
    """(cx, cy, a, b) [mm] from taxels at (x, y) [mm] with pressures p [Pa] for a given beta:
    q = p^(1/beta) = k0 + k1 x + k2 y + k3 x^2 + k4 y^2, weighted so equal pressure noise
    counts equally; None when the quadric is not a cap (no ellipse fits)."""
    q = (p / 1e5) ** (1.0 / beta)
    w = (p / 1e5) ** (1.0 - 1.0 / beta)  # 1 / (dq/dp)
    cols = np.column_stack([np.ones_like(x), x, y, x * x, y * y])
    k = np.linalg.lstsq(cols * w[:, None], q * w, rcond=None)[0]
    if k[3] >= 0 or k[4] >= 0:
        return None
    cx, cy = -k[1] / (2 * k[3]), -k[2] / (2 * k[4])
    q0 = k[0] - k[3] * cx * cx - k[4] * cy * cy
    if q0 <= 0:
        return None
    return cx, cy, math.sqrt(q0 / -k[3]), math.sqrt(q0 / -k[4])


def geometry_jacobian(shape: np.ndarray, x: np.ndarray, y: np.ndarray):
    """The pressure model [Pa] at taxels whose sensing points are at (x, y) [mm] (shape
    (taxels, points); a taxel reports the mean over its points) for the state (cx, cy, a, b
    [mm], ln p_max, beta), and its derivatives in each (taxels x 6)."""
    cx, cy, a, b, ln_pm, beta = shape
    u, v = (x - cx) / a, (y - cy) / b
    phi = 1.0 - u * u - v * v
    inside = phi > 0
    log_phi = np.log(np.where(inside, np.maximum(phi, 0.02), 1.0))  # the slope's singular edge, tamed
    p_pt = np.exp(beta * log_phi + ln_pm) * inside
    slope = beta * p_pt * np.exp(-log_phi)  # dp/dphi at each point
    su, sv = slope * u, slope * v
    model = p_pt.sum(axis=1)  # also the ln p_max column
    jac = np.column_stack([su.sum(axis=1) * (2 / a), sv.sum(axis=1) * (2 / b),
                           (su * u).sum(axis=1) * (2 / a), (sv * v).sum(axis=1) * (2 / b),
                           model, (p_pt * log_phi).sum(axis=1)]) / x.shape[1]
    return jac[:, 4], jac


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
        model, jac = geometry_jacobian(shape, x, y)
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
        xs, ys = taxel_centres_m()
        self.x, self.y = xs * MM, ys * MM
        dx, dy = sensing_offsets_m()
        self.px, self.py = self.x[..., None] + dx * MM, self.y[..., None] + dy * MM  # sensing points
        self.reset()

    def reset(self) -> None:
        self.shape = None  # (cx, cy, a, b) [mm], ln p_max, beta: the state from frame to frame
        self.geometry.reset()

    def update(self, frame_pa: np.ndarray) -> ContactEstimate | None:
        """One frame [Pa] (16 x 16, NaN where dead) -> the contact, or None (no contact)."""
        region = contact_region(frame_pa)
        if region is None:
            self.reset()
            return None
        ring = dilate(region) & ~np.isnan(frame_pa)
        p = frame_pa[ring]
        if self.shape is None:
            first = quadric_geometry(self.x[region], self.y[region], frame_pa[region])
            if first is None:
                return None
            self.shape = np.array([*first, math.log(float(frame_pa[region].max())), 0.5])
        px, py = self.px[ring], self.py[ring]
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


class ContactEstimator(_Layers):
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
