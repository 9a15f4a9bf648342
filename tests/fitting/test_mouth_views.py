"""The inside of a smiling mouth stays inside the head seen from the side."""

from __future__ import annotations

import numpy as np
import pytest
import torch


@pytest.mark.shared_data
@pytest.mark.parametrize("photo", ["Tom_Cruise_avp_2014_4.jpg", "london/003_smiling.jpg"])
def test_mouth_and_teeth_of_a_smiling_photo_stay_inside_the_face_at_every_yaw(
        shared_data, photo):
    """A smile's mouth inside and teeth once stuck out of the face like a beak in side
    views: every vertex of them must project inside the silhouette of the rest of the
    head, from -90 to +90 degrees, with the photo's own expression."""
    from head360cli.drive.views import photo_expression, view_cameras, view_intrinsics
    from head360cli.fitting.config import FitConfig
    from head360cli.fitting.stages import detect_face, fit_shape, load_photo
    from head360cli.geometry.rasterize import rasterize
    from head360cli.mesh.arkit52 import INDEX
    from head360cli.mesh.template import REGION_NAMES

    path = shared_data / "faces" / photo
    if not path.is_file():
        pytest.skip(f"{path} is not there")
    cfg, warnings = FitConfig(), []
    seen = detect_face(load_photo(path, cfg, warnings), cfg, warnings)
    shape = fit_shape(seen, cfg, warnings)
    w = photo_expression(shape.fit.expression)
    assert w[INDEX["mouthSmileLeft"]] + w[INDEX["mouthSmileRight"]] > 0.5  # a smile
    model = shape.model
    verts = torch.tensor(model.vertices(shape.fit.shape, w), dtype=torch.float32)
    inside = [REGION_NAMES.index(r) for r in ("mouth_interior", "teeth", "tongue")]
    inner_faces = np.isin(model.region[model.faces], inside).all(1)
    inner = np.unique(model.faces[inner_faces])
    faces = torch.as_tensor(model.faces)
    size = 256
    k = view_intrinsics(size)
    yaws = np.arange(-90.0, 91.0, 15.0)
    for yaw, c2w in zip(yaws, view_cameras(yaws, 0.0), strict=True):
        w2c = torch.linalg.inv(c2w)
        cam = verts @ w2c[:3, :3].T + w2c[:3, 3]
        px = cam[:, :2] / cam[:, 2:3] * k.diagonal()[:2] + k[:2, 2]
        rest = rasterize(px[None], cam[None, :, 2], faces, size, size,
                         draw=torch.as_tensor(~inner_faces)).face_id[0] >= 0
        p = px[inner].floor().long().clamp(0, size - 1)
        outside = ~rest[p[:, 1], p[:, 0]]
        assert int(outside.sum()) == 0, f"{int(outside.sum())} vertices out at yaw {yaw}"
