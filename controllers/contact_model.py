"""What every contact estimator for the array pressure sensor shares (rig-facts §3): the
contact region in a frame, the pressure model a taxel reads and its derivatives, a first
geometry from the taxels alone, and the estimate's form.

Contact model: an ellipse with centre (cx, cy) and semi-axes a, b [m] along the pad's x and
y (**interpretation**: the paper names no orientation; the pad's axes are taken), and

    p = p_max phi^beta,   phi = 1 - (x - cx)^2/a^2 - (y - cy)^2/b^2   (0 outside)      [Pa]

A taxel reports the mean pressure over its sensing area (about 1.9 mm^2, 1.38 mm square;
:func:`hal.taxel_array.sensing_offsets_m`), which matters at the edge of a contact a few
taxels across: the model is evaluated at 3 x 3 points over each taxel's area and averaged.
The fits run in mm, so their columns are of like size.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from hal.taxel_array import ACCURACY_PA, Contact, sensing_offsets_m, taxel_centres_m

THRESHOLD_PA = 2.0 * ACCURACY_PA  # twice the sensor's +-0.5 % FS: noise alone never qualifies
MIN_TAXELS = 8  # the quadric has 5 coefficients: fewer active taxels give no estimate
EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)
MM = 1e3  # m -> mm
EDGE_PHI = 0.02  # the model's slope dp/dphi is singular at the edge (beta < 1): tamed below this phi


@dataclass(frozen=True)
class ContactEstimate(Contact):
    """An identified contact [m, Pa], with the taxels the fit used, the model's relative RMS
    residual over them before this frame's step (0: it explains every taxel), and, from an
    estimator that knows it, each parameter's 1-sigma uncertainty (same units; NaN when the
    estimator gives none) and the frames its track has estimated, this one included (a young
    track's sigma is its start's linearisation's; 0 from an estimator that keeps no track)."""

    taxels: int = 0
    residual: float = 0.0
    cx_sd: float = math.nan
    cy_sd: float = math.nan
    a_sd: float = math.nan
    b_sd: float = math.nan
    p_max_sd: float = math.nan
    beta_sd: float = math.nan
    force_sd_n: float = math.nan
    track_frames: int = 0


class SensingGrid:
    """The pad's taxel centres (x, y, 16 x 16) and each taxel's sensing points (px, py,
    16 x 16 x 9) [mm]."""

    def __init__(self):
        xs, ys = taxel_centres_m()
        self.x, self.y = xs * MM, ys * MM
        dx, dy = sensing_offsets_m()
        self.px, self.py = self.x[..., None] + dx * MM, self.y[..., None] + dy * MM


def contact_region(frame_pa: np.ndarray) -> np.ndarray | None:
    """The neighbouring-response region (a boolean mask), or None when nothing is touching:
    dead taxels (NaN) take their live neighbours' mean; taxels above ``THRESHOLD_PA`` are
    active; the region is the 8-connected group of active taxels grown from the frame's peak
    (other groups, a second touch or a hot taxel, are left out)."""
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
    """The mask grown by one taxel in the 8 directions (its ring of neighbours added): the
    region's untouched neighbours, whose zeros pin the contact's edge."""
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


def model_jacobian(shape: np.ndarray, x: np.ndarray, y: np.ndarray):
    """The pressure model [Pa] at taxels whose sensing points are at (x, y) [mm] (shape
    (taxels, points); a taxel reports the mean over its points) for the state (cx, cy, a, b
    [mm], ln p_max, beta), and its derivatives in each (taxels x 6). The model is exact up
    to the edge; only its slope there (infinite for beta < 1) is taken at ``EDGE_PHI``."""
    cx, cy, a, b, ln_pm, beta = shape
    u, v = (x - cx) / a, (y - cy) / b
    phi = 1.0 - u * u - v * v
    inside = phi > 0
    log_phi = np.log(np.where(inside, phi, 1.0))
    p_pt = np.exp(beta * log_phi + ln_pm) * inside
    slope = beta * p_pt / np.where(inside, np.maximum(phi, EDGE_PHI), 1.0)  # dp/dphi at each point
    su, sv = slope * u, slope * v
    model = p_pt.sum(axis=1)  # also the ln p_max column
    jac = np.column_stack([su.sum(axis=1) * (2 / a), sv.sum(axis=1) * (2 / b),
                           (su * u).sum(axis=1) * (2 / a), (sv * v).sum(axis=1) * (2 / b),
                           model, (p_pt * log_phi).sum(axis=1)]) / x.shape[1]
    return jac[:, 4].copy(), jac
