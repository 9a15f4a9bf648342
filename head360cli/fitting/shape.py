"""Landmark-based shape fitting: pose, identity code and ARKit weights from 68 points.

The model is bilinear, so the fit alternates linear problems instead of running a
generic optimizer:

1. pose: ``cv2.solvePnP`` (EPnP, closed form, then a Levenberg-Marquardt refinement) on the
   current 3D landmarks;
2. identity ``s`` with ``w`` fixed: landmarks are affine in ``s``; each landmark's
   perspective residual is made linear by its current depth (``f X + (c - u) Z = 0``,
   divided by that depth so it is in pixels) and solved with the Gaussian prior on ``s``;
3. expression ``w`` with ``s`` fixed: the same rows, bounded to [0, 1], with a ridge prior
   reweighted towards sparsity (an iteratively reweighted L1);
4. contour: the 17 jawline landmarks are re-assigned to the silhouette of their
   horizontal slice of the head as seen from the current pose (the FaceScape fitter's
   contour update), so a turned face's outline matches the detector's jawline.

Coordinates follow DESIGN: the model's +y is up and the face looks along +z; the camera is
OpenCV's (x right, y down, z forward), ``X_cam = R X + t``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from head360cli.errors import BadInputError
from head360cli.mesh.bilinear import BilinearModel

__all__ = ["FitConfig", "ShapeFit", "ShapeFitter", "default_focal"]

JAW = np.arange(17)
CHIN_FIXED = (6, 7, 8, 9, 10)  # chin points keep their vertices (the outline's bottom)
DEFAULT_FOCAL_35MM = 50.0


def default_focal(width: int, height: int, focal_35mm: float | None = None) -> float:
    """Focal length in pixels: from a 35 mm-equivalent focal (EXIF
    ``FocalLengthIn35mmFilm``) when known, else a 50 mm-equivalent lens.

    A 35 mm frame is 36 mm wide along the image's longer side.
    """
    f35 = focal_35mm if focal_35mm and focal_35mm > 0 else DEFAULT_FOCAL_35MM
    return f35 / 36.0 * max(width, height)


@dataclasses.dataclass(frozen=True)
class FitConfig:
    """Settings of the shape fit."""

    iterations: int = 4
    """Alternations of pose, identity, expression and contour."""
    identity_prior: float = 1.0
    """Weight of the identity prior (in units of one pixel squared per standard deviation)."""
    expression_prior: float = 20.0
    """Ridge weight on the ARKit weights (pixels squared); reweighted towards L1."""
    fit_expression: bool = True
    """Solve for ``w`` (else keep it zero)."""
    contour: bool = True
    """Slide the jawline landmarks to the silhouette."""


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


class ShapeFitter:
    """Fits the bilinear model to 68 landmarks; reusable across faces.

    Args:
        model: The bilinear model.
        config: Fit settings.
    """

    def __init__(self, model: BilinearModel, config: FitConfig = FitConfig()) -> None:
        self.model = model
        self.config = config
        lm = np.asarray(model.landmarks, dtype=np.int64)
        self.contour_candidates = self._contour_candidates(model, lm)
        verts = np.unique(np.concatenate([lm, *self.contour_candidates]))
        self.sub_vertices = verts
        self.pos_of = {int(v): i for i, v in enumerate(verts)}
        k = model.rank
        nb = model.neutral_basis.astype(np.float64)[:, verts]  # (K, L, 3)
        self.a0 = model.neutral_mean.astype(np.float64)[verts]  # (L, 3)
        self.b0 = nb
        # Dense blendshape blocks at these vertices: mean (52, L, 3), basis (K, 52, L, 3).
        self.me = np.zeros((52, len(verts), 3))
        self.be = np.zeros((k, 52, len(verts), 3))
        index = {int(v): i for i, v in enumerate(verts)}
        sel = np.nonzero(np.isin(model.expr_vertex, verts))[0]
        rows = np.array([index[int(v)] for v in model.expr_vertex[sel]], dtype=np.int64)
        shapes = model.expr_shape[sel].astype(np.int64)
        self.me[shapes, rows] = model.expr_mean[sel]
        self.be[:, shapes, rows] = model.expr_basis[:, sel].astype(np.float64)
        # Flat layouts for the two contractions of each iteration (one BLAS call each).
        # float32: these products are memory-bound, and the bases are float16 on disk.
        self.be_by_code = self.be.reshape(k, -1).astype(np.float32)  # s @ -> (52, L, 3)
        self.be_by_shape = np.ascontiguousarray(
            self.be.transpose(1, 0, 2, 3)).reshape(52, -1).astype(np.float32)
        self.b0_flat = self.b0.reshape(k, -1)
        cov = model.code_cov + 1e-12 * np.eye(k)
        evals, evecs = np.linalg.eigh(cov)
        self.prior_prec = (evecs / np.clip(evals, 1e-18, None)) @ evecs.T  # C^-1
        # Shapes that move none of these vertices (the eyes' gaze) cannot be fitted.
        self.visible_shapes = np.nonzero(np.abs(self.me).reshape(52, -1).max(1) > 0)[0]
        self.code_mean = model.code_mean.astype(np.float64)
        self.landmarks = lm

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

    def _points(self, s: np.ndarray, w: np.ndarray) -> np.ndarray:
        """``(L, 3)`` positions of the sub-model's vertices."""
        n = len(self.sub_vertices)
        base = self.a0 + (s @ self.b0_flat).reshape(n, 3)
        shapes = self.me + (s.astype(np.float32) @ self.be_by_code).reshape(52, n, 3)
        return base + np.tensordot(w, shapes, 1)

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

    def _pose(self, points, uv, f, centre, guess=None):
        import cv2

        k = np.array([[f, 0, centre[0]], [0, f, centre[1]], [0, 0, 1.0]])
        obj = np.ascontiguousarray(points, dtype=np.float64)
        img = np.ascontiguousarray(uv, dtype=np.float64)
        if guess is None:
            ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_EPNP)
            if not ok:
                raise BadInputError("could not find a head pose for these landmarks")
            if tvec[2, 0] < 0:  # EPnP's mirror solution behind the camera
                ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, flags=cv2.SOLVEPNP_SQPNP)
        else:
            rvec, tvec = cv2.Rodrigues(guess[0])[0], guess[1].reshape(3, 1).copy()
        ok, rvec, tvec = cv2.solvePnP(obj, img, k, None, rvec, tvec, useExtrinsicGuess=True,
                                      flags=cv2.SOLVEPNP_ITERATIVE)
        return cv2.Rodrigues(rvec)[0], tvec.reshape(3)

    # ----------------------------------------------------------------- public
    def fit(self, landmarks2d: np.ndarray, image_size: tuple[int, int],
            focal: float | None = None) -> ShapeFit:
        """Fit pose, identity and expression to 68 landmarks.

        Args:
            landmarks2d: ``(68, 2)`` pixel coordinates (x right, y down).
            image_size: ``(width, height)``.
            focal: Focal length in pixels (default :func:`default_focal`).

        Raises:
            BadInputError: Landmarks of the wrong shape, non-finite, or degenerate (all in
                one point, on one line, or spanning fewer than 8 pixels).
        """
        t0 = time.perf_counter()
        uv = np.asarray(landmarks2d, dtype=np.float64)
        self._check(uv)
        width, height = image_size
        f = float(focal) if focal else default_focal(width, height)
        centre = np.array([width / 2.0, height / 2.0])
        cfg = self.config
        k = self.model.rank
        s = self.code_mean.copy()
        w = np.zeros(52)
        lm_rows = np.array([self.pos_of[int(v)] for v in self.landmarks])
        inner = np.arange(17, 68)
        pts = self._points(s, w)
        rot, t = self._pose(pts[lm_rows[inner]], uv[inner], f, centre)
        timings = {"pose": 0.0, "identity": 0.0, "expression": 0.0, "contour": 0.0}
        rows = lm_rows.copy()
        ew = np.ones(52)
        n = len(self.sub_vertices)
        ident = self.b0 + (w.astype(np.float32) @ self.be_by_shape).reshape(k, n, 3)  # affine in w
        for _ in range(cfg.iterations):
            tc = time.perf_counter()
            if cfg.contour:
                rows = self._slide_contour(pts, rows, rot, t, f, centre)
            timings["contour"] += time.perf_counter() - tc
            # Identity with w fixed: landmarks are a + G s.
            ti = time.perf_counter()
            cam_z = (pts[rows] @ rot.T + t)[:, 2]
            m, off = self._rows(cam_z, rot, t, f, centre, uv)
            a = self.a0[rows] + np.tensordot(w, self.me[:, rows], 1)
            g = np.transpose(ident[:, rows], (1, 2, 0))  # (n, 3, K)
            a_rows = np.einsum("ij,ijk->ik", m, np.repeat(g, 2, axis=0))
            b_rows = -(np.einsum("ij,ij->i", m, np.repeat(a, 2, axis=0)) + off)
            lam2 = cfg.identity_prior
            # Normal equations (K x K) are far cheaper than a least-squares solver here.
            lhs = a_rows.T @ a_rows + lam2 * self.prior_prec
            rhs = a_rows.T @ b_rows + lam2 * (self.prior_prec @ self.code_mean)
            s = np.linalg.solve(lhs, rhs)
            base = self.a0 + (s @ self.b0_flat).reshape(n, 3)
            # The blendshapes at this s (affine in s).
            shapes = self.me + (s.astype(np.float32) @ self.be_by_code).reshape(52, n, 3)
            timings["identity"] += time.perf_counter() - ti
            # Expression with s fixed: landmarks are c + H w; bounded, ridge reweighted
            # towards sparsity.
            if cfg.fit_expression:
                te = time.perf_counter()
                h = np.transpose(shapes[:, rows], (1, 2, 0))  # (n, 3, 52)
                a_rows = np.einsum("ij,ijk->ik", m, np.repeat(h, 2, axis=0))
                b_rows = -(np.einsum("ij,ij->i", m, np.repeat(base[rows], 2, axis=0)) + off)
                vis = self.visible_shapes
                w_vis = self._bounded(a_rows[:, vis], b_rows,
                                      cfg.expression_prior * ew[vis], w[vis])
                w = np.zeros(52)
                w[vis] = w_vis
                ew = 1.0 / (np.abs(w) + 0.05)
                ew = ew / ew.mean()
                ident = self.b0 + (w.astype(np.float32) @ self.be_by_shape).reshape(k, n, 3)
                timings["expression"] += time.perf_counter() - te
            # Pose with the updated landmarks.
            tp = time.perf_counter()
            pts = base + np.tensordot(w, shapes, 1)
            rot, t = self._pose(pts[rows], uv, f, centre, guess=(rot, t))
            timings["pose"] += time.perf_counter() - tp
        fitted, _ = self._project(pts[rows], rot, t, f, centre)
        timings["total"] = time.perf_counter() - t0
        return ShapeFit(shape=s, expression=w, rotation=rot, translation=t, focal=f,
                        centre=centre, landmarks_fitted=fitted,
                        landmark_vertices=self.sub_vertices[rows], timings=timings)

    def _bounded(self, a: np.ndarray, b: np.ndarray, ridge: np.ndarray, w0: np.ndarray
                 ) -> np.ndarray:
        """``min |A w - b|^2 + sum ridge_i w_i^2`` with ``0 <= w <= 1`` (projected
        coordinate descent on the normal equations, warm-started)."""
        q = a.T @ a + np.diag(ridge)
        r = a.T @ b
        w = w0.copy()
        diag = np.diag(q)
        for _ in range(5):  # warm-started across the fit's iterations
            for i in range(len(w)):
                g = r[i] - q[i] @ w + diag[i] * w[i]
                w[i] = min(1.0, max(0.0, g / diag[i]))
        return w

    def _slide_contour(self, pts, rows, rot, t, f, centre):
        rows = rows.copy()
        for k in JAW:
            if k in CHIN_FIXED:
                continue
            cand = np.array([self.pos_of[int(v)] for v in self.contour_candidates[k]])
            proj, _ = self._project(pts[cand], rot, t, f, centre)
            # The model's x (the subject's left, +x) shows on the image's right for a
            # frontal camera; the outline of a slice is its extreme in that direction.
            side = np.sign(self.a0[cand[0], 0])
            toward = proj[:, 0] if side > 0 else -proj[:, 0]
            rows[k] = cand[int(np.argmax(toward))]
        return rows

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
