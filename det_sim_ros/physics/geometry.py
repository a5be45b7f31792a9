"""
The actuator's shape in 3D from the model state (no ROS).

Both beams' deflected centre lines, the DET between them and, for plate scenes, the plate. Used
by the node's markers (markers.py).

Each cell stands upright in its own frame (SI units, m): the fixed beam ends at the origin, the
beam axis along +z, so the moving end (where the DET and the plate pull) is at height
z = l - y, and Delta-y = y0 - y is the rise of that end. Beam A deflects along +x by w(s), beam
B is its mirror image (-w); the model's factor 2 on every beam integral is this pair. The DET is
the membrane between the beam ends on the z axis.

The centre line is computed from the same Ritz basis and kinematics as the model: at the
material coordinate s, the deflection is w(s) = sum_j S_j(s) q_j and the height is
s - y(s) with the partial end shortening y(s) = int_0^s e(w') ds, e = w'^2/2 ('paper'),
w'^2/2 + w'^4/8 ('consistent') or 1 - sqrt(1 - w'^2) ('exact'), so y(l) is the model's y. The
reference point (x = 2l/3 simply supported, l/2 fixed) is one of the samples: its deflection is
the published q.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .shapes import REFERENCE_POINT

__all__ = ['ActuatorGeometry', 'CellShape', 'PlateShape', 'layout_offsets']

_GAUSS_NODES = 6          # per segment: exact for w'^2 up to 11th degree (n_ritz-term bases)
DET_WIDTH_MIN = 1.0e-3    # m: the drawn DET is at least this thick (0.6 mm real) to be seen


@dataclasses.dataclass
class CellShape:
    """
    One cell's shape in its own frame (m).

    Beams A/B as (n, 3) points, the DET box and the reference point on beam A.
    """

    beam_a: np.ndarray
    beam_b: np.ndarray
    height: float            # l - y: z of the moving end
    det_thickness: float     # n d0 / lambda (drawn at least DET_WIDTH_MIN)
    det_width: float         # electrode width A0 / l0
    reference: np.ndarray    # (3,): beam A at the reference point; its x is the published q


@dataclasses.dataclass
class PlateShape:
    """The rigid plate in the common layout frame: centre (3,), rotation about x (rad)."""

    centre: np.ndarray
    tilt: float
    width: float


def layout_offsets(model) -> np.ndarray:
    """
    Return the (n_dets, 3) base positions of the cells in a common frame (m).

    The plate's cells at y = -w/2 and +w/2, an array's copies side by side along y, one cell at
    the origin.
    """
    scene = model.scene
    n = model.n_inputs
    offsets = np.zeros((n, 3))
    if scene.structure['type'] == 'plate':
        w = scene.structure['plate_width']
        offsets[:, 1] = np.linspace(-w / 2.0, w / 2.0, n)
    elif n > 1:
        pitch = 1.5 * max(ph.A0 / ph.l0 for ph in scene.cell_physics())
        offsets[:, 1] = pitch * np.arange(n)
    return offsets


class _CellSampler:
    """Precomputed basis values of one cell at the drawing samples (linear maps of q)."""

    def __init__(self, basis, kinematics: str, physics, n_points: int):
        length = basis.length
        s_ref = REFERENCE_POINT[basis.beam] * length
        s = np.unique(np.r_[np.linspace(0.0, length, n_points), s_ref])
        self.ref_index = int(np.argmin(np.abs(s - s_ref)))
        self.s = s
        self.S = basis.values(s)                                  # (n, r): w = S q
        xi, wg = np.polynomial.legendre.leggauss(_GAUSS_NODES)
        a, b = s[:-1, None], s[1:, None]
        nodes = 0.5 * (b - a) * (xi[None, :] + 1.0) + a           # (n - 1, g)
        weights = (0.5 * (b - a) * wg[None, :]).reshape(-1)
        self.B1 = basis.values(nodes.reshape(-1), 1)              # w' at the Gauss nodes
        # y(s_k) = sum over the segments below s_k of their quadrature: one matrix product
        segment = np.repeat(np.arange(len(s) - 1), _GAUSS_NODES)
        self.cumulative = (segment[None, :] < np.arange(len(s))[:, None]) * weights[None, :]
        self.half_cumulative = 0.5 * self.cumulative
        self.S_B1 = np.vstack([self.S, self.B1])
        self.n_samples = len(s)
        self.kinematics = kinematics
        self.physics = physics
        self.det_width = physics.A0 / physics.l0
        self.length = length

    def profile(self, coords):
        """
        Return (w, z) at the samples: deflection and height of beam A, m.

        Few numpy calls: this runs for every marker frame.
        """
        both = self.S_B1 @ coords
        w, wp = both[:self.n_samples], both[self.n_samples:]
        wp2 = wp * wp
        if self.kinematics == 'exact':
            e = 1.0 - np.sqrt(np.maximum(1.0 - wp2, 0.0))
        elif self.kinematics == 'consistent':
            e = wp2 * (0.5 + 0.125 * wp2)
        else:
            return w, self.s - self.half_cumulative @ wp2       # e = w'^2 / 2
        return w, self.s - self.cumulative @ e

    def det_thickness(self, height: float) -> float:
        """Return the drawn DET thickness n d0 / lambda at the cell height l - y (m)."""
        ph = self.physics
        return max(ph.n * ph.d0 * ph.l0 / height, DET_WIDTH_MIN)

    def shape(self, coords) -> CellShape:
        w, z = self.profile(coords)
        zeros = np.zeros_like(w)
        beam_a = np.column_stack([w, zeros, z])
        beam_b = np.column_stack([-w, zeros, z])
        height = float(z[-1])
        return CellShape(beam_a, beam_b, height, self.det_thickness(height), self.det_width,
                         beam_a[self.ref_index].copy())


class ActuatorGeometry:
    """
    Shapes of all cells of a model at a state x.

    :param model: a built :class:`det_sim_ros.physics.model.Model`.
    :param n_points: samples along each beam (the reference point is added).
    """

    def __init__(self, model, n_points: int = 41):
        self.model = model
        self.scene = model.scene
        self.names = list(model.input_names)
        self._cells = [_CellSampler(basis, self.scene.fidelity, ph, n_points)
                       for basis, ph in zip(model.bases, self.scene.cell_physics())]
        self.offsets = layout_offsets(model)
        self.has_plate = self.scene.structure['type'] == 'plate'
        self.n_points = len(self._cells[0].s)
        a = model.arrays
        self.slices = [a.cell_slice(c) for c in range(a.n_cells)]
        self.samplers = self._cells

    def cells(self, x) -> list:
        """Return one :class:`CellShape` per DET (DET order), each in its own frame."""
        return [cell.shape(x[s]) for s, cell in zip(self.slices, self._cells)]

    def plate(self, cells) -> PlateShape | None:
        """Return the plate on the cells' moving ends (common frame), or None without a plate."""
        if not self.has_plate:
            return None
        heights = np.array([c.height for c in cells])
        w = self.scene.structure['plate_width']
        centre = np.array([0.0, 0.0, heights.mean()])
        tilt = float(np.arctan2(heights[-1] - heights[0], w))   # > 0: the right side is higher
        return PlateShape(centre, tilt, w)
