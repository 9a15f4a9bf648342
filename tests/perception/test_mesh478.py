"""The 478-point face mesh, the 68 iBUG points read from it, and the blendshape scores."""

import numpy as np
import pytest

from head360cli.perception.mesh478 import crop_transform


def test_crop_transform_levels_a_turned_line_and_fits_the_side():
    m = crop_transform(np.array([100.0, 50.0]), 40.0, np.radians(30), 256)
    a, b = np.array([100.0, 50.0]), np.array([100.0, 50.0]) + 10 * np.array(
        [np.cos(np.radians(30)), np.sin(np.radians(30))])
    pa, pb = m[:, :2] @ a + m[:, 2], m[:, :2] @ b + m[:, 2]
    np.testing.assert_allclose(pa, [128, 128])
    assert pb[1] == pytest.approx(128) and pb[0] == pytest.approx(128 + 64)


def test_mesh_on_the_astronaut_and_its_mirror_agree():
    import skimage.data

    from head360cli.fitting.landmarks import MIRROR_68, LandmarkDetector

    img = skimage.data.astronaut()
    face = LandmarkDetector("auto").detect_one(img)
    assert face.mesh.shape == (478, 3) and face.blendshapes.shape == (52,)
    x0, _, x1, _ = face.box
    inside = (face.mesh[:, 0] > x0 - 20) & (face.mesh[:, 0] < x1 + 20)
    assert inside.all()
    mirrored = LandmarkDetector("auto").detect_one(np.ascontiguousarray(img[:, ::-1]))
    back = mirrored.landmarks.copy()
    back[:, 0] = 511 - back[:, 0]
    err = np.linalg.norm(back[MIRROR_68] - face.landmarks, axis=1).mean()
    assert err < 2.5, err  # measured 1.2 px on a face 90 px wide


def test_the_ibug_map_is_a_convex_combination_of_mesh_points():
    from head360cli.perception.ibug68 import load_ibug68_map

    index, weight = load_ibug68_map()
    assert index.shape == weight.shape and index.shape[0] == 68
    assert (weight >= 0).all()
    np.testing.assert_allclose(weight.sum(1), 1.0, atol=1e-5)
    assert index.max() < 468


def test_fit_ibug68_map_recovers_a_known_combination():
    from head360cli.perception.ibug68 import fit_ibug68_map, to_ibug68

    rng = np.random.default_rng(0)
    true_index = rng.choice(468, size=(68, 2), replace=True)
    meshes = [rng.normal(size=(478, 2)) * 50 + 200 for _ in range(30)]
    mapping = (true_index, np.full((68, 2), 0.5))
    targets = [to_ibug68(m, mapping) for m in meshes]
    index, weight = fit_ibug68_map(meshes, targets, candidates=468)
    got = [to_ibug68(m, (index, weight)) for m in meshes]
    assert max(np.abs(g - t).max() for g, t in zip(got, targets, strict=True)) < 0.05


def test_smiles_score_higher_than_neutral_faces(shared_data):
    """mouthSmile of the London set's first ten people, smiling against neutral: higher
    for at least nine of them, and by 0.3 on average."""
    from head360cli.fitting.landmarks import LandmarkDetector
    from head360cli.io.images import load_image
    from head360cli.mesh.arkit52 import INDEX

    det = LandmarkDetector("auto")
    smile = [INDEX["mouthSmileLeft"], INDEX["mouthSmileRight"]]
    folder = shared_data / "faces" / "london"
    pairs = []
    for n in sorted(folder.glob("*_neutral.jpg"))[:10]:
        s = n.with_name(n.name.replace("neutral", "smiling"))
        pairs.append([det.detect_one(load_image(p).pixels).blendshapes[smile].mean()
                      for p in (n, s)])
    pairs = np.array(pairs)
    assert (pairs[:, 1] > pairs[:, 0]).sum() >= 9, pairs
    assert pairs[:, 1].mean() > pairs[:, 0].mean() + 0.3, pairs
