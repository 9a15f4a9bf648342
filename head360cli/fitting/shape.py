"""Landmark-based shape fitting: pose, identity code and ARKit weights from 68 points.

The model is bilinear, so the fit alternates linear problems instead of running a
generic optimizer:

1. pose: at the start ``cv2.solvePnP`` (EPnP, closed form, then Levenberg-Marquardt) on
   the mean head's inner landmarks; in each iteration one damped Gauss-Newton step on the
   current 3D landmarks (the pose starts close, so one step per iteration is enough);
2. identity ``s`` with ``w`` fixed: landmarks are affine in ``s``; each landmark's
   perspective residual is made linear by its current depth (``f X + (c - u) Z = 0``,
   divided by that depth so it is in pixels) and solved with the Gaussian prior on ``s``;
3. expression ``w`` with ``s`` fixed: the same rows, bounded to [0, 1] (an active-set
   solve), with a ridge prior reweighted towards sparsity (an iteratively reweighted L1);
4. contour: the 17 jawline landmarks are re-assigned to the silhouette of their
   horizontal slice of the head as seen from the current pose (the FaceScape fitter's
   contour update), so a turned face's outline matches the detector's jawline.

Landmarks are points on the surface (a triangle and barycentric weights, see
``BilinearModel.landmark_tri``), so the model is linear in them as in its vertices. Only the
model rows at the 68 landmarks and the jawline's candidate vertices are read: the fixed
points' blocks are laid out once per fitter, the expression basis as the (landmark, shape)
pairs that move.

Coordinates follow DESIGN: the model's +y is up and the face looks along +z; the camera is
OpenCV's (x right, y down, z forward), ``X_cam = R X + t``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from head360cli.errors import BadInputError
from head360cli.geometry.rig import RIG_TARGET
from head360cli.mesh.bilinear import BilinearModel

__all__ = ["FOCAL_35MM_RANGE", "ShapeFit", "ShapeFitConfig", "ShapeFitter", "check_camera",
           "check_focal", "default_focal", "frontal_jaw"]


def _mv(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``a @ v`` over the last axis as one 2D product (numpy's batched matmul over the
    leading axes is many times slower for these small blocks)."""
    return (a.reshape(-1, a.shape[-1]) @ v).reshape(a.shape[:-1])


def _head_centre_seen(rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``(3,)`` the head's centre (the rig's target) in camera coordinates."""
    return rot @ np.asarray(RIG_TARGET, np.float64) + t


JAW = np.arange(17)
CHIN_FIXED = (6, 7, 8, 9, 10)  # chin points keep their vertices (the outline's bottom)
DEFAULT_FOCAL_35MM = 50.0


def check_camera(focal: float | None, distance: float | None) -> None:
    """Refuse a focal length (pixels) or camera distance (metres) that is given but not a
    positive number (``None``: not given). The pipeline calls it before any work: a
    negative focal had failed deep in the inversion, a NaN one as an internal error.

    Raises:
        BadInputError: Either is zero, negative or not finite.
    """
    for name, value, unit in (("focal length", focal, "pixels"),
                              ("camera distance", distance, "metres")):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise BadInputError(f"expected a positive {name} in {unit}, found {value}")


FOCAL_35MM_RANGE = (4.0, 4000.0)
"""Lenses a given focal length may stand for, in 35 mm-equivalent millimetres: beyond
them a fit ends with no face on the texture (a 10-pixel focal on a 512-pixel photo) or
in a singular camera (1e9 pixels)."""


def check_focal(focal: float | None, width: int, height: int) -> None:
    """Refuse a focal length (pixels of a ``width`` x ``height`` image) that no lens has:
    outside :data:`FOCAL_35MM_RANGE` in 35 mm terms (``None``: not given).

    Raises:
        BadInputError: The focal is outside the range.
    """
    if focal is None:
        return
    longer = max(width, height)
    lo, hi = (f / 36.0 * longer for f in FOCAL_35MM_RANGE)
    if not lo <= focal <= hi:
        raise BadInputError(
            f"expected a focal length between {lo:.0f} and {hi:.0f} pixels for this "
            f"{width}x{height} photo (a {FOCAL_35MM_RANGE[0]:g}-{FOCAL_35MM_RANGE[1]:g} mm "
            f"lens in 35 mm terms), found {focal:g}")


def default_focal(width: int, height: int, focal_35mm: float | None = None) -> float:
    """Focal length in pixels: from a 35 mm-equivalent focal (EXIF
    ``FocalLengthIn35mmFilm``) when known and within :data:`FOCAL_35MM_RANGE`, else a
    50 mm-equivalent lens.

    A 35 mm frame is 36 mm wide along the image's longer side.
    """
    lo, hi = FOCAL_35MM_RANGE
    f35 = focal_35mm if focal_35mm and lo <= focal_35mm <= hi else DEFAULT_FOCAL_35MM
    return f35 / 36.0 * max(width, height)


@dataclasses.dataclass(frozen=True)
class ShapeFitConfig:
    """Settings of the shape fit."""

    iterations: int = 8
    """Alternations of pose, identity, expression and contour. Leave-landmarks-out
    cross-validation on dlib's example faces (error of held-out landmarks over face size):
    6 -> 2.29 %, 8 -> 2.26 %, 12 -> 2.25 %, 20 -> 2.24 %. 8 keeps the fit within its
    10 ms budget on two CPU cores; 12 or more buys the last 0.5 %."""
    identity_prior: float = 1.0
    """Weight of the identity prior (in units of one pixel squared per standard deviation)."""
    expression_prior: float = 20.0
    """Ridge weight on the ARKit weights (pixels squared); reweighted towards L1."""
    opposed: float = 4.0
    """Weight of the squared excess over 1 of the sum of each pair of opposed blendshapes
    (:data:`~head360cli.mesh.arkit52.OPPOSED`: a wide eye and a squint, a smile and a
    pucker), relative to the geometric mean of the two shapes' own squared landmark
    moves, so the two cannot both saturate. Without it a smiling portrait fitted 16 of 52
    weights at exactly 1, pucker beside smile and wide eyes beside squints. 0: none."""
    fit_expression: bool = True
    """Solve for ``w`` (else keep it zero)."""
    contour: bool = True
    """Slide the jawline landmarks to the silhouette."""
    dense_weight: float = 0.25
    """Weight of each dense point (the face mesh's, when the fitter has them) against a
    68-point landmark's 1: 0.25 gives the 420-odd dense points about 1.5 times the 68's
    say. With dense points both priors grow with the data, by ``1 + dense_weight * N /
    68``, so that they hold the same sway over the fit as with the 68 alone: on the
    London set's first 20 people (neutral against smiling portraits), the neutral heads
    of a person's two fits differed by 1.29 mm with the priors as for 68 points and
    1.19 mm scaled, with 1.6 and 0.7 weights at their limit per fit."""


@dataclasses.dataclass
class ShapeFit:
    """The result of a fit.

    Attributes:
        shape: ``(K,)`` identity code.
        expression: ``(52,)`` ARKit weights.
        rotation: ``(3, 3)`` model-to-camera rotation.
        translation: ``(3,)`` metres.
        focal: pixels; principal point ``centre`` (cx, cy).
        centre: ``(2,)``.
        landmarks_fitted: ``(68, 2)`` pixels of the model's landmarks (contour slid).
        landmark_vertices: ``(68,)`` vertex used for each landmark.
        timings: seconds per stage.
        dense_fitted: ``(N, 2)`` pixels of the model's dense points, or ``None``.
    """

    shape: np.ndarray
    expression: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    focal: float
    centre: np.ndarray
    landmarks_fitted: np.ndarray
    landmark_vertices: np.ndarray
    timings: dict[str, float]
    dense_fitted: np.ndarray | None = None

    def landmarks_3d(self, model) -> np.ndarray:
        """``(68, 2)`` pixels of the bilinear ``model``'s 68 landmarks as fixed points on
        its surface, projected: AFLW2000-3D's convention, where the jawline is the 3D
        jaw's, against :attr:`landmarks_fitted`, whose jawline follows the silhouette
        (300-W's). The jawline's fixed points are where this head's neutral face shows
        its outline from straight ahead (:func:`frontal_jaw`), so a turned face's far
        jaw is drawn on the jaw, not on the cheek's silhouette."""
        v = model.vertices(self.shape, self.expression)
        points = (v[model.landmark_tri] * model.landmark_bary[..., None]).sum(1)
        sliding, vertices = frontal_jaw(model, model.vertices(self.shape, np.zeros(52)))
        points[sliding] = v[vertices]
        cam = points @ self.rotation.T + self.translation
        z = np.maximum(cam[:, 2], 1e-6)
        return np.stack([self.focal * cam[:, 0] / z + self.centre[0],
                         self.focal * cam[:, 1] / z + self.centre[1]], 1)

    def distance(self) -> float:
        """The camera's distance in metres to the head's centre
        (:data:`~head360cli.geometry.rig.RIG_TARGET`)."""
        return float(np.linalg.norm(_head_centre_seen(self.rotation, self.translation)))

    def euler_degrees(self) -> dict[str, float]:
        """Yaw, pitch and roll in degrees, in the renderer's camera convention: the view
        that a camera at this yaw and pitch around an unturned head would give (yaw > 0
        shows more of the head's left side; pitch > 0 looks down on it)."""
        # The camera's orbit around an unturned head, in model axes: C = H^T with
        # H = diag(1, -1, -1) R the head's rotation relative to the frontal pose. A camera
        # at (yaw, pitch) has C = Ry(yaw) Rx(-pitch) Rz(roll).
        c = (np.diag([1.0, -1.0, -1.0]) @ self.rotation).T
        yaw = np.degrees(np.arctan2(c[0, 2], c[2, 2]))
        pitch = np.degrees(np.arcsin(np.clip(c[1, 2], -1.0, 1.0)))
        roll = np.degrees(np.arctan2(c[1, 0], c[1, 1]))
        return {"yaw": float(yaw), "pitch": float(pitch), "roll": float(roll)}


_JAW_SLICES: dict[int, tuple] = {}
"""Per bilinear model (by identity): its sliding jawline points, their slices and sides."""


def frontal_jaw(model: BilinearModel, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The jawline landmarks that slide (``(12,)`` iBUG indices) and, for each, the vertex
    of its slice that is the outline of ``vertices (V, 3)`` (a head of ``model``) seen
    from straight ahead: the slice's extreme towards its own side, in model x."""
    cached = _JAW_SLICES.get(id(model))
    if cached is None or cached[0] is not model:
        lm = np.asarray(model.landmarks, dtype=np.int64)
        sliding = np.array([k for k in JAW if k not in CHIN_FIXED])
        cached = _JAW_SLICES[id(model)] = (model, sliding,
                                           ShapeFitter._contour_candidates(model, lm),
                                           np.sign(model.neutral_mean[lm[sliding], 0]))
    _, sliding, slices, side = cached
    chosen = np.array([slices[k][np.argmax(vertices[slices[k], 0] * sd)]
                       for k, sd in zip(sliding, side, strict=True)])
    return sliding, chosen


class ShapeFitter:
    """Fits the bilinear model to 68 landmarks, and to dense points when given; reusable
    across faces.

    Args:
        model: The bilinear model.
        config: Fit settings.
        dense: ``(tri (N, 3), bary (N, 3))``: N more points on the surface (the face
            mesh's, :func:`head360cli.fitting.calibrate.register_face_mesh`) that
            :meth:`fit` then takes as ``dense2d``, fixed (they do not slide).
    """

    def __init__(self, model: BilinearModel, config: ShapeFitConfig = ShapeFitConfig(),
                 dense: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        import cv2  # noqa: F401  (loaded here, with the model, not in the first fit)

        self.model = model
        self.config = config
        lm = np.asarray(model.landmarks, dtype=np.int64)
        self.landmarks = lm
        self.contour_candidates = self._contour_candidates(model, lm)
        # Landmarks in solver order: the fixed ones (inner face and chin), then the jawline
        # points that slide; ``order`` maps solver order back to iBUG numbering.
        self.sliding = np.array([k for k in JAW if k not in CHIN_FIXED])
        self.fixed = np.setdiff1d(np.arange(68), self.sliding)
        self.order = np.concatenate([self.fixed, self.sliding])
        self.unorder = np.argsort(self.order)
        # Every vertex a sliding point can take, and each point's candidates among them.
        cand = np.unique(np.concatenate([self.contour_candidates[k] for k in self.sliding]))
        self.cand_vertices = cand
        where = {int(v): i for i, v in enumerate(cand)}
        width = max(len(self.contour_candidates[k]) for k in self.sliding)
        self.cand_table = np.array([  # (12, width), padded by repeating the first candidate
            [where[int(v)] for v in self.contour_candidates[k]]
            + [where[int(self.contour_candidates[k][0])]] * (width - len(
                self.contour_candidates[k])) for k in self.sliding])
        # Each sliding point starts on its own landmark vertex.
        self.start_choice = np.searchsorted(cand, lm[self.sliding])
        self.cand_side = np.sign(model.neutral_mean[lm[self.sliding], 0]).astype(np.float64)
        tri = np.asarray(model.landmark_tri)[self.fixed]
        bary = np.asarray(model.landmark_bary, dtype=np.float64)[self.fixed]
        self.n_dense = 0 if dense is None else len(dense[0])
        if dense is not None:
            tri = np.concatenate([tri, np.asarray(dense[0])])
            bary = np.concatenate([bary, np.asarray(dense[1], dtype=np.float64)])
        self.n_fix = len(tri)  # solver rows before the sliding points
        self.prior_scale = 1.0 + config.dense_weight * self.n_dense / 68.0
        # the 68's rows among the solver's, in solver order
        self.rows68 = np.concatenate([np.arange(len(self.fixed)),
                                      self.n_fix + np.arange(len(self.sliding))])
        # rows that set the starting pose: the inner face's landmarks and dense points
        self.inner_rows = np.concatenate([
            np.nonzero(self.fixed >= 17)[0], len(self.fixed) + np.arange(self.n_dense)])
        self.fix_blocks = self._embedded_blocks(model, tri, bary)
        self.cand_blocks = self._blocks(model, cand)
        # The fixed points' blendshape basis as the (landmark, shape) pairs that move
        # (about a third of them): ``s Be`` reads only those.
        bw = self.fix_blocks.pop("bw")
        self.pair_l, self.pair_j = np.nonzero(np.abs(bw).max(axis=(1, 2)) > 0)
        self.pair_basis = np.ascontiguousarray(bw[self.pair_l, :, :, self.pair_j])  # (P,3,K)
        del self.fix_blocks["bs"]
        self.fix_bw = bw
        self._gathered: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # sliding rows, cached
        k = model.rank
        cov = model.code_cov + 1e-12 * np.eye(k)
        evals, evecs = np.linalg.eigh(cov)
        self.prior_prec = (evecs / np.clip(evals, 1e-18, None)) @ evecs.T  # C^-1
        self.code_mean = model.code_mean.astype(np.float64)
        # Shapes that move none of the landmark or outline vertices (the eyes' gaze) cannot
        # be fitted.
        moved = np.abs(np.concatenate([self.fix_blocks["me"], self.cand_blocks["me"]]))
        self.visible_shapes = np.nonzero(moved.max(axis=(0, 1)) > 0)[0]
        # the opposed pairs among them, as columns of the visible shapes' solve
        from head360cli.mesh.arkit52 import INDEX, OPPOSED

        column = {int(k): n for n, k in enumerate(self.visible_shapes)}
        self.opposed_pairs = np.array(
            [(column[INDEX[a]], column[INDEX[b]]) for a, b in OPPOSED
             if INDEX[a] in column and INDEX[b] in column], dtype=np.int64).reshape(-1, 2)

    @staticmethod
    def _blocks(model: BilinearModel, verts: np.ndarray) -> dict[str, np.ndarray]:
        """The model restricted to ``verts`` (n of them), in the layouts the solver reads.

        Returns:
            ``a0`` (n, 3) mean neutral; ``b0`` (n, 3, K) identity basis of the neutral;
            ``me`` (n, 3, 52) mean blendshapes; ``bw`` (n, 3, K, 52) and ``bs``
            (n, 3, 52, K) the blendshapes' identity basis, float32 (these contractions are
            memory-bound and the bases are float16 on disk).
        """
        k, n = model.rank, len(verts)
        index = {int(v): i for i, v in enumerate(verts)}
        a0 = model.neutral_mean[verts].astype(np.float64)
        b0 = np.ascontiguousarray(  # rows first: widening all of a float16 basis is slow
            model.neutral_basis[:, verts].astype(np.float64).transpose(1, 2, 0))
        me = np.zeros((n, 3, 52))
        be = np.zeros((n, 3, k, 52), dtype=np.float32)
        sel = np.nonzero(np.isin(model.expr_vertex, verts))[0]
        rows = np.array([index[int(v)] for v in model.expr_vertex[sel]], dtype=np.int64)
        shapes = model.expr_shape[sel].astype(np.int64)
        me[rows, :, shapes] = model.expr_mean[sel]
        be[rows, :, :, shapes] = model.expr_basis[:, sel].astype(np.float32).transpose(1, 2, 0)
        return {"a0": a0, "b0": b0, "me": me, "bw": be,
                "bs": np.ascontiguousarray(be.transpose(0, 1, 3, 2))}

    @classmethod
    def _embedded_blocks(cls, model: BilinearModel, tri: np.ndarray, bary: np.ndarray
                         ) -> dict[str, np.ndarray]:
        """:meth:`_blocks` for points on the surface: ``tri`` ``(n, 3)`` vertex ids with
        barycentric weights ``bary`` ``(n, 3)`` (the model is linear in its vertices)."""
        uniq, inv = np.unique(tri, return_inverse=True)
        per_vertex = cls._blocks(model, uniq)
        out = {}
        for key, arr in per_vertex.items():
            sub = arr[inv.reshape(-1)].reshape(*tri.shape, *arr.shape[1:])
            wts = bary.reshape(*tri.shape, *([1] * (arr.ndim - 1))).astype(arr.dtype)
            out[key] = np.ascontiguousarray((sub * wts).sum(1))
        return out

    # ----------------------------------------------------------------- model pieces
    @staticmethod
    def outline_mask(model: BilinearModel) -> np.ndarray:
        """``(V,)`` vertices that can carry the face's outline: face and neck (regions 1
        and 6 in REGION_NAMES order), not eyes, ears or teeth. All, without regions."""
        if model.region.size and model.region.max() > 0:
            return np.isin(model.region, [1, 6])
        return np.ones(model.num_vertices, dtype=bool)

    @staticmethod
    def contour_slice(mean: np.ndarray, outline: np.ndarray, vertex: int) -> np.ndarray:
        """The vertices a jawline landmark at ``vertex`` slides over: those at its height
        (its own grid row, on the mean head), on its side of the face, in front of the ears.
        """
        p = mean[vertex]
        near = outline & (np.abs(mean[:, 1] - p[1]) < 0.0015) & (
            np.sign(mean[:, 0]) == np.sign(p[0])) & (mean[:, 2] > -0.01)
        return np.union1d(np.nonzero(near)[0], [vertex])

    @classmethod
    def _contour_candidates(cls, model: BilinearModel, lm: np.ndarray) -> list[np.ndarray]:
        """For each jawline landmark, its slice (the chin points keep their vertex)."""
        mean = model.neutral_mean.astype(np.float64)
        outline = cls.outline_mask(model)
        return [np.array([lm[k]]) if k in CHIN_FIXED else
                cls.contour_slice(mean, outline, int(lm[k])) for k in JAW]

    def _landmark_bases(self, choice: np.ndarray) -> dict[str, np.ndarray]:
        """The small blocks (a0, b0, me) at the current landmark vertices, solver order:
        the fixed points, then the chosen candidate of each sliding point."""
        fb, cb = self.fix_blocks, self.cand_blocks
        return {key: np.concatenate([fb[key], cb[key][choice]]) for key in ("a0", "b0", "me")}

    def _contract(self, key: str, vec: np.ndarray, choice: np.ndarray) -> np.ndarray:
        """The blendshapes' identity basis at the landmarks contracted with ``vec``:
        ``Be w`` (n, 3, K) for ``key="bw"``, ``s Be`` (n, 3, 52) for ``key="bs"``. The fixed
        points' ``s Be`` uses their (landmark, shape) pairs; the sliding points' rows are
        gathered."""
        v = vec.astype(np.float32)
        cached = self._gathered.get(key)
        if cached is None or not np.array_equal(cached[0], choice):
            cached = self._gathered[key] = (choice, self.cand_blocks[key][choice])
        if key == "bw":
            return np.concatenate([_mv(self.fix_bw, v), _mv(cached[1], v)])
        # s Be: each pair's (3,) delta for this code
        fixed = np.zeros((self.n_fix, 3, 52), dtype=np.float32)
        fixed[self.pair_l, :, self.pair_j] = _mv(self.pair_basis, v)
        return np.concatenate([fixed, _mv(cached[1], v)])

    def _candidate_points(self, s: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``(C, 3)`` positions of the outline candidates, without the identity-expression
        interaction (a sub-millimetre term that does not change which point is outermost)."""
        cb = self.cand_blocks
        return cb["a0"] + _mv(cb["b0"], s) + _mv(cb["me"], w)

    # ----------------------------------------------------------------- solver pieces
    def _rows(self, pts_cam_depth, rot, t, f, centre, uv):
        """Linear perspective rows ``M P + m`` (2n, 3) acting on model points, in pixels."""
        n = len(uv)
        z = np.maximum(pts_cam_depth, 1e-3)[:, None]
        cu = centre[0] - uv[:, 0:1]
        cv = centre[1] - uv[:, 1:2]
        mx = (f * rot[0][None] + cu * rot[2][None]) / z  # (n, 3)
        my = (f * rot[1][None] + cv * rot[2][None]) / z
        ox = (f * t[0] + cu[:, 0] * t[2]) / z[:, 0]
        oy = (f * t[1] + cv[:, 0] * t[2]) / z[:, 0]
        m = np.empty((2 * n, 3))
        m[0::2], m[1::2] = mx, my
        off = np.empty(2 * n)
        off[0::2], off[1::2] = ox, oy
        return m, off

    @staticmethod
    def _project(points, rot, t, f, centre):
        cam = points @ rot.T + t
        z = np.maximum(cam[:, 2], 1e-6)
        return np.stack([f * cam[:, 0] / z + centre[0], f * cam[:, 1] / z + centre[1]], 1), cam

    @classmethod
    def _pose(cls, points, uv, f, centre):
        """The starting pose: EPnP (closed form), then Gauss-Newton steps."""
        import cv2

        k = np.array([[f, 0, centre[0]], [0, f, centre[1]], [0, 0, 1.0]])
        obj = np.ascontiguousarray(points, dtype=np.float64)
        img = np.ascontiguousarray(uv, dtype=np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_EPNP)
        if not ok:
            raise BadInputError("could not find a head pose for these landmarks")
        if tvec[2, 0] < 0:  # EPnP's mirror solution behind the camera
            ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_SQPNP)
        rot, t = cv2.Rodrigues(rvec)[0], tvec.reshape(3)
        for _ in range(3):
            rot, t = cls._pose_step(obj, img, f, centre, rot, t)
        return rot, t

    @staticmethod
    def _pose_step(points, uv, f, centre, rot, t, sw=None):
        """One damped Gauss-Newton step of the pose on the reprojection error: within the
        alternation the pose starts close, and each iteration takes another step.

        The update rotates the posed points, ``R <- exp([d]x) R``, and shifts ``t``.
        ``sw (n,)``: square roots of the points' weights (default all 1).
        """
        import cv2

        rp = points @ rot.T  # (n, 3)
        cam = rp + t
        iz = 1.0 / cam[:, 2]
        x, y = cam[:, 0] * iz, cam[:, 1] * iz
        res = np.concatenate([f * x + centre[0] - uv[:, 0], f * y + centre[1] - uv[:, 1]])
        # d(u, v)/d cam = f/z (1, 0, -x) and f/z (0, 1, -y); d cam/d(rotation, t) is
        # (-[rp]x, I), so the rotation columns are rp x d(u, v)/d cam, written out.
        rx, ry, rz = rp[:, 0], rp[:, 1], rp[:, 2]
        one, zero = np.ones_like(x), np.zeros_like(x)
        ju = np.stack([-x * ry, rz + x * rx, -ry, one, zero, -x], 1)
        jv = np.stack([-y * ry - rz, y * rx, rx, zero, one, -y], 1)
        jac = np.concatenate([ju, jv]) * np.concatenate([f * iz, f * iz])[:, None]
        if sw is not None:
            row = np.concatenate([sw, sw])
            jac, res = jac * row[:, None], res * row
        jtj = jac.T @ jac
        jtj.flat[::7] *= 1.0 + 1e-6  # Levenberg damping
        step = -np.linalg.solve(jtj, jac.T @ res)
        rot = cv2.Rodrigues(step[:3])[0] @ rot
        return rot, t + step[3:]

    # ----------------------------------------------------------------- public
    def fit(self, landmarks2d: np.ndarray, image_size: tuple[int, int],
            focal: float | None = None, weights: np.ndarray | None = None,
            distance: float | None = None, turn: float = 0.0,
            dense2d: np.ndarray | None = None,
            expression0: np.ndarray | None = None) -> ShapeFit:
        """Fit pose, identity and expression to 68 landmarks (and the dense points).

        Args:
            landmarks2d: ``(68, 2)`` pixel coordinates (x right, y down).
            dense2d: ``(N, 2)`` pixels of the dense points, required when the fitter was
                made with ``dense``; their weight is the config's ``dense_weight``.
            expression0: ``(52,)`` ARKit weights read from the photo (the face mesh's
                blendshape scores): the expression starts there and its ridge pulls
                towards them instead of towards neutral. ``None``: neutral.
            image_size: ``(width, height)``.
            focal: Focal length in pixels (default :func:`default_focal`).
            weights: ``(68,)`` non-negative weight per landmark (default all 1); a zero
                leaves a landmark out of the fit (it is still reported as fitted).
            distance: The camera's distance in metres to the head's centre
                (:data:`~head360cli.geometry.rig.RIG_TARGET` in model axes), when
                known. Landmarks alone hardly tell a small head near the camera from a
                large one further away (the perspective cue is weak at a metre); a known
                distance fixes the head's size. ``None``: free.
            turn: Degrees (counter-clockwise on screen) that turn the image so that the
                face is about upright (a face found in a turned copy,
                :attr:`~head360cli.fitting.landmarks.DetectedFace.turn`). The fit runs on
                the landmarks turned so about the principal point, which is the same
                camera rolled about its axis, and its pose is rolled back: the jawline's
                sliding reads the outline across the image's rows, so a head lying on
                its side fitted as it lies gets the wrong outline (the astronaut turned
                90 degrees: yaw 6.8 degrees instead of -3.4).

        Raises:
            BadInputError: Landmarks of the wrong shape, non-finite, or degenerate (all in
                one point, on one line, or spanning fewer than 8 pixels), or a focal
                length or distance that is not a positive number.
        """
        t0 = time.perf_counter()
        uv_in = np.asarray(landmarks2d, dtype=np.float64)
        self._check(uv_in)
        check_camera(focal, distance)
        if self.n_dense:
            if dense2d is None or np.shape(dense2d) != (self.n_dense, 2) or not np.isfinite(
                    dense2d).all():
                raise BadInputError(f"expected ({self.n_dense}, 2) finite dense points, "
                                    f"found {None if dense2d is None else np.shape(dense2d)}")
            dense2d = np.asarray(dense2d, dtype=np.float64)
        w0 = np.zeros(52)
        if expression0 is not None:
            w0 = np.asarray(expression0, dtype=np.float64)
            if w0.shape != (52,) or not np.isfinite(w0).all():
                raise BadInputError(f"expected (52,) finite starting weights, found "
                                    f"{w0.shape}")
            w0 = np.clip(w0, 0.0, 1.0)
        if turn:
            return self._fit_turned(uv_in, image_size, focal, weights, distance, turn,
                                    dense2d, w0)
        sw68 = self._check_weights(weights)
        # solver order: fixed landmarks, dense points, then the sliding jawline
        sw = np.concatenate([sw68[self.fixed], np.full(self.n_dense, np.sqrt(
            self.config.dense_weight)), sw68[self.sliding]])
        uv = np.concatenate([uv_in[self.fixed], dense2d if self.n_dense else np.zeros(
            (0, 2)), uv_in[self.sliding]])
        width, height = image_size
        f = float(focal) if focal else default_focal(width, height)
        centre = np.array([width / 2.0, height / 2.0])
        cfg = self.config
        s = self.code_mean.copy()
        w = w0.copy()
        vis = self.visible_shapes
        used = np.nonzero(sw > 0)[0]
        row_w = np.repeat(sw, 2)[:, None]
        choice = self.start_choice.copy()
        blocks = self._landmark_bases(choice)
        inner = np.intersect1d(used, self.inner_rows)
        pts = blocks["a0"] + _mv(blocks["b0"], s)
        rot, t = self._pose(pts[inner], uv[inner], f, centre)
        t = self._at_distance(rot, t, distance)
        timings = {"pose": 0.0, "identity": 0.0, "expression": 0.0, "contour": 0.0}
        ew = np.ones(52)
        for _ in range(cfg.iterations):
            tc = time.perf_counter()
            if cfg.contour:
                choice = self._slide(self._candidate_points(s, w), rot, t, f, centre)
                blocks = self._landmark_bases(choice)
            timings["contour"] += time.perf_counter() - tc
            # Identity with w fixed: landmarks are c + G s, G = B0 + Be w.
            ti = time.perf_counter()
            g = blocks["b0"] + self._contract("bw", w, choice)
            c = blocks["a0"] + _mv(blocks["me"], w)
            cam_z = ((c + _mv(g, s)) @ rot.T + t)[:, 2]
            m, off = self._rows(cam_z, rot, t, f, centre, uv)
            m, off = m * row_w, off * row_w[:, 0]
            a_rows = np.einsum("ij,ijk->ik", m, np.repeat(g, 2, axis=0))
            b_rows = -(np.einsum("ij,ij->i", m, np.repeat(c, 2, axis=0)) + off)
            lam2 = cfg.identity_prior * self.prior_scale
            # Normal equations (K x K) are far cheaper than a least-squares solver here.
            lhs = a_rows.T @ a_rows + lam2 * self.prior_prec
            rhs = a_rows.T @ b_rows + lam2 * (self.prior_prec @ self.code_mean)
            s = np.linalg.solve(lhs, rhs)
            # The blendshapes at this s: H = Me + s Be; landmarks are base + H w.
            base = blocks["a0"] + _mv(blocks["b0"], s)
            h = blocks["me"] + self._contract("bs", s, choice)
            timings["identity"] += time.perf_counter() - ti
            # Expression with s fixed: bounded, ridge reweighted towards sparsity.
            if cfg.fit_expression:
                te = time.perf_counter()
                a_rows = np.einsum("ij,ijk->ik", m, np.repeat(h[:, :, vis], 2, axis=0))
                b_rows = -(np.einsum("ij,ij->i", m, np.repeat(base, 2, axis=0)) + off)
                w_prev, w = w, np.zeros(52)
                w[vis] = self._bounded(a_rows, b_rows,
                                       cfg.expression_prior * self.prior_scale * ew[vis],
                                       w_prev[vis], self.opposed_pairs, cfg.opposed,
                                       target=w0[vis])
                ew = 1.0 / (np.abs(w - w0) + 0.05)
                ew = ew / ew.mean()
                timings["expression"] += time.perf_counter() - te
            # Pose with the updated landmarks.
            tp = time.perf_counter()
            pts = base + _mv(h, w)
            rot, t = self._pose_step(pts[used], uv[used], f, centre, rot, t, sw[used])
            t = self._at_distance(rot, t, distance)
            timings["pose"] += time.perf_counter() - tp
        fitted, _ = self._project(pts, rot, t, f, centre)
        vertices = np.concatenate([self.landmarks[self.fixed], self.cand_vertices[choice]])
        timings["total"] = time.perf_counter() - t0
        return ShapeFit(shape=s, expression=w, rotation=rot, translation=t, focal=f,
                        centre=centre, landmarks_fitted=fitted[self.rows68][self.unorder],
                        landmark_vertices=vertices[self.unorder], timings=timings,
                        dense_fitted=fitted[len(self.fixed):self.n_fix] if self.n_dense
                        else None)

    def _fit_turned(self, uv: np.ndarray, image_size: tuple[int, int], focal, weights,
                    distance, turn: float, dense2d: np.ndarray | None = None,
                    expression0: np.ndarray | None = None) -> ShapeFit:
        """:meth:`fit` of ``uv`` turned by ``turn`` degrees about the principal point,
        rolled back: a roll ``q`` of the camera about its axis turns every projection by
        the same angle about the principal point, so ``R = q^T R'`` and ``t = q^T t'``."""
        centre = np.array([image_size[0] / 2.0, image_size[1] / 2.0])
        c, s_ = np.cos(np.radians(turn)), np.sin(np.radians(turn))
        a = np.array([[c, s_], [-s_, c]])  # cv2's turn: x right, y down, counter-clockwise
        fit = self.fit((uv - centre) @ a.T + centre, image_size, focal, weights, distance,
                       dense2d=None if dense2d is None else (dense2d - centre) @ a.T + centre,
                       expression0=expression0)
        q = np.eye(3)
        q[:2, :2] = a
        return dataclasses.replace(
            fit, rotation=q.T @ fit.rotation, translation=q.T @ fit.translation,
            landmarks_fitted=(fit.landmarks_fitted - centre) @ a + centre,
            dense_fitted=None if fit.dense_fitted is None
            else (fit.dense_fitted - centre) @ a + centre)

    @staticmethod
    def _at_distance(rot: np.ndarray, t: np.ndarray, distance: float | None) -> np.ndarray:
        """``t`` moved so that the head's centre lies ``distance`` from the camera, along
        its current line of sight (where it projects does not change); the identity step
        that follows then fits the head's size."""
        if distance is None:
            return t
        seen = _head_centre_seen(rot, t)
        return seen * (distance / np.linalg.norm(seen)) - (seen - t)

    @staticmethod
    def _bounded(a: np.ndarray, b: np.ndarray, ridge: np.ndarray, w0: np.ndarray,
                 pairs: np.ndarray | None = None, opposed: float = 0.0,
                 rounds: int = 3, target: np.ndarray | None = None) -> np.ndarray:
        """``min |A w - b|^2 + sum ridge_i (w_i - target_i)^2 + sum_pairs c_ij max(0, w_i +
        w_j - 1)^2`` with ``0 <= w <= 1`` (``target`` zero by default): the column ``pairs
        (P, 2)`` (opposed blendshapes) pay for any sum over 1,
        ``c_ij = opposed * sqrt(q_ii q_jj)``, so both cannot saturate.

        A few rounds of an active-set method, warm-started from ``w0``: the weights at a
        bound whose gradient pushes them outwards stay there, the free ones get the exact
        solution of the reduced system, clipped to the box; the pairs over 1 at the start
        of a round have their penalty in that round's system (a convex, piecewise
        quadratic term). Across the fit's iterations the active set settles, so a few
        rounds per call are enough.
        """
        q0 = a.T @ a
        q0.flat[:: len(q0) + 1] += ridge  # the diagonal
        r0 = a.T @ b
        if target is not None:
            r0 = r0 + ridge * target
        use_pairs = pairs is not None and len(pairs) > 0 and opposed > 0
        if use_pairs:
            i, j = pairs[:, 0], pairs[:, 1]
            c = opposed * np.sqrt(np.diag(a.T @ a)[i] * np.diag(a.T @ a)[j])
        w = np.clip(w0, 0.0, 1.0)
        for _ in range(rounds + (3 if use_pairs else 0)):
            q, r = q0, r0
            if use_pairs:
                over = w[i] + w[j] > 1.0
                if over.any():  # c (w_i + w_j - 1)^2 = c (e.w)^2 - 2 c e.w + c
                    q, r = q0.copy(), r0.copy()
                    for ii, jj, cc in zip(i[over], j[over], c[over], strict=True):
                        q[ii, ii] += cc
                        q[jj, jj] += cc
                        q[ii, jj] += cc
                        q[jj, ii] += cc
                        r[ii] += cc
                        r[jj] += cc
            grad = q @ w - r
            free = ~(((w <= 0.0) & (grad > 0)) | ((w >= 1.0) & (grad < 0)))
            if not free.any():
                break
            qf = q[free]
            rhs = r[free] - qf[:, ~free] @ w[~free]
            new = w.copy()
            new[free] = np.clip(np.linalg.solve(qf[:, free], rhs), 0.0, 1.0)
            step = np.abs(new - w).max()
            w = new
            if step < 1e-6:
                break
        return w

    def _slide(self, cand_pts, rot, t, f, centre) -> np.ndarray:
        """For each sliding jawline point, the candidate (an index into
        ``cand_vertices``) on the silhouette of its slice in this view: the slice's extreme
        towards its own side of the image."""
        proj, _ = self._project(cand_pts, rot, t, f, centre)
        # The model's x (the subject's left, +x) shows on the image's right for a frontal
        # camera; the outline of a slice is its extreme in that direction.
        toward = proj[self.cand_table, 0] * self.cand_side[:, None]
        return self.cand_table[np.arange(len(self.cand_table)), np.argmax(toward, axis=1)]

    def contour_landmarks(self, vertices: np.ndarray, rot: np.ndarray, t: np.ndarray,
                          focal: float, centre: np.ndarray) -> np.ndarray:
        """``(68, 3)`` landmark points of a head with its jawline slid to the silhouette
        seen from this camera (what a detector reports as the face's outline).

        Args:
            vertices: ``(V, 3)`` the head's vertices (model coordinates).
            rot, t: Model-to-camera rotation ``(3, 3)`` and translation ``(3,)``.
            focal, centre: Pinhole intrinsics in pixels.
        """
        choice = self._slide(vertices[self.cand_vertices], rot, t, focal, centre)
        points = self.model.landmark_points(vertices)
        points[self.sliding] = vertices[self.cand_vertices[choice]]
        return points

    @staticmethod
    def _check_weights(weights) -> np.ndarray:
        """Square roots of the landmark weights, ``(68,)``."""
        if weights is None:
            return np.ones(68)
        wt = np.asarray(weights, dtype=np.float64)
        if wt.shape != (68,) or not np.isfinite(wt).all() or (wt < 0).any():
            raise BadInputError(
                f"expected 68 finite non-negative landmark weights, found shape {wt.shape}")
        if np.count_nonzero(wt[17:]) < 6:
            raise BadInputError(
                f"expected at least 6 weighted inner landmarks (17-67) for a pose, found "
                f"{np.count_nonzero(wt[17:])}")
        return np.sqrt(wt)

    @staticmethod
    def _check(uv: np.ndarray) -> None:
        if uv.shape != (68, 2):
            raise BadInputError(f"expected 68 landmarks as (68, 2), found {uv.shape}")
        if not np.isfinite(uv).all():
            raise BadInputError("landmarks hold NaN or infinite values")
        span = uv.max(0) - uv.min(0)
        if span.min() < 8.0:
            raise BadInputError(
                f"degenerate landmarks: they span {span[0]:.1f} x {span[1]:.1f} px; expected "
                "a face at least 8 pixels across")
        centred = uv - uv.mean(0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[1] < 1e-3 * sv[0]:
            raise BadInputError("degenerate landmarks: all 68 lie on one line")
