"""`--profile` / `--radius` of the command line: the exact sphere, the paraboloid and the
pyramids (parse_profile)."""

import math

import numpy as np
import pytest

import jaxcontact as jc
from jaxcontact_cli._common import UsageError, parse_profile


def test_sphere_paraboloid_and_radius_shorthand():
    prof, radius = parse_profile("sphere:5e-6", None)
    assert isinstance(prof, jc.Sphere) and float(prof.R) == 5e-6 and radius is None
    prof, radius = parse_profile("paraboloid:5e-6", None)
    assert isinstance(prof, jc.Parabola) and radius == 5e-6
    # --radius keeps its earlier meaning (the paraboloid): old results reproduce
    prof, radius = parse_profile(None, 5e-6)
    assert isinstance(prof, jc.Parabola) and radius == 5e-6


@pytest.mark.parametrize("sides", [3, 4])
def test_pyramids(sides):
    face, _ = parse_profile(f"pyramid{sides}:20", None)
    same, _ = parse_profile(f"pyramid{sides}:20,face", None)
    assert isinstance(face, jc.Cone)
    assert float(face.half_angle) == float(same.half_angle)
    # by the published factor: tan(psi) = (pi/2) k tan(alpha_face)
    k = {3: 0.8887, 4: 1.4906 / 2}[sides]
    np.testing.assert_allclose(math.tan(float(face.half_angle)),
                               0.5 * math.pi * k * math.tan(math.radians(20)), rtol=1e-13)
    # an edge angle is larger than the face angle of the same pyramid
    edge_deg = math.degrees(math.atan(math.tan(math.radians(20)) / math.cos(math.pi / sides)))
    edge, _ = parse_profile(f"pyramid{sides}:{edge_deg!r},edge", None)
    np.testing.assert_allclose(float(edge.half_angle), float(face.half_angle), rtol=1e-12)


@pytest.mark.parametrize("spec, match", [
    ("pyramid4:95", "pyramid4:DEG"),
    ("pyramid3:20,side", "bad numbers"),
    ("pyramid4:20,face,edge", "bad numbers"),
    ("pyramid4:20,30", "takes 1 number"),
    ("sphere:2", "sphere:R"),
    ("paraboloid:-1", "paraboloid:R"),
    ("ellipse:1", "paraboloid:R, cone:DEG, pyramid4"),
])
def test_bad_profiles(spec, match):
    with pytest.raises(UsageError, match=match):
        parse_profile(spec, None)
    with pytest.raises(UsageError, match="paraboloid:R or sphere:R"):
        parse_profile("sphere:1e-5", 1e-5)


def test_a_shape_registered_once_is_parsed_checked_listed_and_helped(monkeypatch):
    # adding an indenter to the command line is one entry of PROFILE_SHAPES: parsing,
    # the range checks of its values, the list in the error messages and the help follow
    from jaxcontact_cli import _common

    shapes = dict(_common.PROFILE_SHAPES)
    shapes["blunt"] = _common.ProfileShape(
        (("R", "m", {"high": 1.0}), ("DEG", "degrees", {"high": 89.9})),
        "a test shape", lambda v, _m: jc.Cone(half_angle=math.radians(v[1])))
    monkeypatch.setattr(_common, "PROFILE_SHAPES", shapes)
    prof, radius = parse_profile("blunt:1e-6,30", None)
    assert isinstance(prof, jc.Cone) and radius is None
    assert float(prof.half_angle) == pytest.approx(math.radians(30))
    with pytest.raises(UsageError, match="blunt:DEG"):
        parse_profile("blunt:1e-6,95", None)
    with pytest.raises(UsageError, match="blunt takes 2 number"):
        parse_profile("blunt:1e-6", None)
    with pytest.raises(UsageError, match="or blunt:R,DEG"):
        parse_profile("ellipse:1", None)
    assert "blunt:R,DEG (a test shape)" in _common.profile_help()
