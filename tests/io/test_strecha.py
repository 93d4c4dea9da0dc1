"""Strecha benchmark cameras (photorecon.io.strecha): P = K [Rᵀ | −Rᵀ C], R camera-to-world, C the centre."""
import numpy as np
import pytest

from photorecon.cameras import look_at, project
from photorecon.errors import InputDataError
from photorecon.io.dataset import read_model
from photorecon.io.strecha import read_strecha, read_strecha_camera

K = np.array([[1200.0, 0.0, 310.25], [0.0, 1150.0, 235.5], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 640, 480


def _camera_text(R_world_from_cam, C, K=K, dist="0 0 0", size=f"{WIDTH} {HEIGHT}") -> str:
    """A .camera file written by hand, in the benchmark's layout (not through photorecon)."""
    rows = [" ".join(f"{x:.17g}" for x in r) + " " for r in K]  # the benchmark's files end rows with a space
    rows.append(dist)
    rows += [" ".join(f"{x:.17g}" for x in r) for r in R_world_from_cam]
    rows.append(" ".join(f"{x:.17g}" for x in C))
    rows.append(size)
    return "\n".join(rows) + "\n"


def _known_camera():
    """A camera at C looking at the origin; R = its camera-to-world rotation (columns: camera axes in world)."""
    C = np.array([4.0, -3.0, 1.5])
    cam_from_world = look_at(C, [0.2, 0.1, 0.0])
    return C, cam_from_world[:3, :3].T


def test_strecha_camera_projects_like_P_by_hand(tmp_path):
    C, R = _known_camera()
    path = tmp_path / "0007.jpg.camera"
    path.write_text(_camera_text(R, C))
    view = read_strecha_camera(path)
    assert view.name == "0007" and view.image_file == "0007.jpg"
    assert view.intrinsics.size == (WIDTH, HEIGHT)
    np.testing.assert_allclose(view.center, C, atol=1e-12)
    # P = K [Rᵀ | −Rᵀ C], homogeneous division, pixel (0,0) = centre of the top-left pixel in both
    P = K @ np.hstack([R.T, (-R.T @ C)[:, None]])
    X = np.array([[0.3, -0.2, 0.4], [0.0, 0.0, 0.0], [-0.5, 0.6, -0.1]])
    x = (P @ np.hstack([X, np.ones((3, 1))]).T).T
    expected = x[:, :2] / x[:, 2:]
    uv, z = project(X, view.intrinsics, view.cam_from_world)
    np.testing.assert_allclose(uv, expected, atol=1e-9)
    np.testing.assert_allclose(z, x[:, 2], atol=1e-9)
    # semantic: the camera looks at (0.2, 0.1, 0): that point lands on the principal point, in front
    uv0, z0 = project(np.array([[0.2, 0.1, 0.0]]), view.intrinsics, view.cam_from_world)
    np.testing.assert_allclose(uv0[0], [K[0, 2], K[1, 2]], atol=1e-9)
    assert z0[0] > 0


def test_strecha_folder_and_dataset_through_read_model(tmp_path):
    C, R = _known_camera()
    cams = tmp_path / "scene" / "gt_dense_cameras"
    cams.mkdir(parents=True)
    (tmp_path / "scene" / "images").mkdir()
    # a second camera 2 m along x, rotation rounded to 6 digits as in the benchmark's files
    (cams / "0001.jpg.camera").write_text(_camera_text(np.round(R, 6), C + [2.0, 0.0, 0.0]))
    (cams / "0000.jpg.camera").write_text(_camera_text(R, C))
    for where in (tmp_path / "scene", cams):
        model = read_model(where)
        assert [v.name for v in model.views] == ["0000", "0001"]
        assert len(model.points) == 0
        np.testing.assert_allclose(model.views[1].center - model.views[0].center, [2.0, 0.0, 0.0], atol=1e-12)
        R1 = model.views[1].cam_from_world[:3, :3]
        np.testing.assert_allclose(R1 @ R1.T, np.eye(3), atol=1e-12)  # snapped to a proper rotation
        np.testing.assert_allclose(R1.T, R, atol=2e-6)
    assert [v.name for v in read_strecha(cams).views] == ["0000", "0001"]


@pytest.mark.parametrize("mutate, needle", [
    (lambda t: "\n".join(t.splitlines()[:-1]) + "\n", "expected 9 lines"),
    (lambda t: t.replace("0 0 0", "0 zero 0"), "not a Strecha camera file"),
    (lambda t: t.replace("0 0 0", "0.1 0 0"), "distortion"),
    (lambda t: t.replace(f"{WIDTH} {HEIGHT}", "640.5 480"), "integer image size"),
])
def test_strecha_bad_file_is_one_line_naming_the_file(tmp_path, mutate, needle):
    C, R = _known_camera()
    path = tmp_path / "0003.jpg.camera"
    path.write_text(mutate(_camera_text(R, C)))
    with pytest.raises(InputDataError) as err:
        read_model(tmp_path)
    msg = str(err.value)
    assert str(path) in msg and needle in msg and "\n" not in msg


def test_strecha_rejects_reflection_and_skew(tmp_path):
    C, R = _known_camera()
    path = tmp_path / "0000.jpg.camera"
    path.write_text(_camera_text(R @ np.diag([1.0, 1.0, -1.0]), C))
    with pytest.raises(InputDataError, match="not a rotation"):
        read_strecha_camera(path)
    skewed = K.copy()
    skewed[0, 1] = 2.0
    path.write_text(_camera_text(R, C, K=skewed))
    with pytest.raises(InputDataError, match=str(path)):
        read_strecha_camera(path)
    with pytest.raises(InputDataError, match="no Strecha"):
        read_strecha(tmp_path / "missing")
