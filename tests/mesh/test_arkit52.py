from head360cli.mesh import arkit52 as ak


def test_names_are_52_unique_in_apple_order():
    assert len(ak.ARKIT52) == 52
    assert len(set(ak.ARKIT52)) == 52
    # Spot checks of Apple's ARFaceAnchor order (also the Live Link UDP packet order).
    assert ak.ARKIT52[0] == "eyeBlinkLeft"
    assert ak.ARKIT52[14:18] == ("jawForward", "jawLeft", "jawRight", "jawOpen")
    assert ak.ARKIT52[21:23] == ("mouthLeft", "mouthRight")
    assert ak.ARKIT52[-1] == "tongueOut"
    assert ak.INDEX["jawOpen"] == 17


def test_mirror_is_an_involution_that_swaps_sides():
    for i, j in enumerate(ak.MIRROR_INDEX):
        assert ak.MIRROR_INDEX[j] == i
    assert ak.MIRROR["eyeBlinkLeft"] == "eyeBlinkRight"
    assert ak.MIRROR["jawLeft"] == "jawRight"
    assert ak.MIRROR["eyeLookInLeft"] == "eyeLookInRight"
    assert ak.MIRROR["jawOpen"] == "jawOpen"
    central = [n for n in ak.ARKIT52 if ak.MIRROR[n] == n]
    assert sorted(central) == sorted(ak.MERGED_SPLITS)
    assert len(central) == 12  # 20 left/right pairs and 12 central shapes


def test_aliases_map_onto_canonical_names():
    cases = {
        "EyeBlinkLeft": "eyeBlinkLeft",  # Live Link Face
        "eyeBlinkLeft": "eyeBlinkLeft",  # ARKit / MediaPipe
        "eye_blink_left": "eyeBlinkLeft",
        "eyeBlink_L": "eyeBlinkLeft",
        "eyeBlink_R": "eyeBlinkRight",
        "mouthSmile.L": "mouthSmileLeft",
        "jaw_L": "jawLeft",
        "blendShape.jawOpen": "jawOpen",
        "browInnerUp_L": "browInnerUp",
        "cheekPuff_R": "cheekPuff",
        " JawOpen ": "jawOpen",
    }
    for column, expected in cases.items():
        assert ak.canonical_name(column) == expected, column


def test_non_blendshape_columns_are_not_matched():
    for column in ["Timecode", "BlendshapeCount", "_neutral", "HeadYaw", "LeftEyePitch",
                   "time", "eyeBlink", "smile_L", ""]:
        assert ak.canonical_name(column) is None, column


def test_split_part_recognises_halves_of_central_shapes_only():
    assert ak.split_part("browInnerUp_L") == "Left"
    assert ak.split_part("cheekPuff_R") == "Right"
    assert ak.split_part("browInnerUp") is None
    assert ak.split_part("eyeBlink_L") is None  # a sided shape, not a half
