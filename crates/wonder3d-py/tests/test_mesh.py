"""Mesh and ViewSet: numpy in and out, files and trimesh, bit for bit."""

import errno

import numpy as np
import pytest

import wonder3d
from conftest import SPOT


def random_mesh(seed=0, n=200, m=300):
    rng = np.random.default_rng(seed)
    vertices = rng.normal(size=(n, 3)).astype(np.float32)
    faces = np.stack([rng.permutation(n)[:3] for _ in range(m)]).astype(np.uint32)
    return vertices, faces


def test_numpy_round_trip_is_bit_exact():
    vertices, faces = random_mesh()
    mesh = wonder3d.Mesh(vertices, faces)
    assert mesh.vertices.dtype == np.float32 and mesh.vertices.shape == (200, 3)
    assert mesh.faces.dtype == np.uint32 and mesh.faces.shape == (300, 3)
    assert np.array_equal(mesh.vertices.view(np.uint32), vertices.view(np.uint32))
    assert np.array_equal(mesh.faces, faces)
    assert (mesh.vertex_count, mesh.triangle_count) == (200, 300)


def test_other_dtypes_and_lists_are_converted():
    vertices, faces = random_mesh()
    mesh = wonder3d.Mesh(vertices.astype(np.float64), faces.astype(np.int64))
    assert np.array_equal(mesh.vertices, vertices)
    small = wonder3d.Mesh([[0, 0, 0.0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert small.triangle_count == 1


@pytest.mark.parametrize("extension", ["ply", "glb", "obj"])
def test_file_round_trip_is_bit_exact(tmp_path, extension):
    spot = wonder3d.Mesh.load(SPOT)
    path = tmp_path / f"spot.{extension}"
    spot.save(path)
    back = wonder3d.Mesh.load(path)
    assert np.array_equal(back.vertices.view(np.uint32), spot.vertices.view(np.uint32))
    assert np.array_equal(back.faces, spot.faces)


def test_trimesh_round_trip_is_bit_exact():
    trimesh = pytest.importorskip("trimesh")
    vertices, faces = random_mesh(1)
    mesh = wonder3d.Mesh(vertices, faces)
    tm = mesh.to_trimesh()
    assert isinstance(tm, trimesh.Trimesh)
    assert np.array_equal(tm.vertices, vertices.astype(np.float64))
    assert np.array_equal(tm.faces, faces.astype(np.int64))
    back = wonder3d.Mesh.from_trimesh(tm)
    assert back == mesh
    # And from a file trimesh wrote.
    spot = wonder3d.Mesh.load(SPOT)
    # (from_trimesh takes the geometry: vertices and faces.)
    assert wonder3d.Mesh.from_trimesh(spot.to_trimesh()) == wonder3d.Mesh(spot.vertices, spot.faces)


def test_textured_mesh_to_trimesh(tmp_path, spot_views_dir):
    pytest.importorskip("trimesh")
    pytest.importorskip("PIL")
    views = wonder3d.ViewSet.load(spot_views_dir)
    textured = wonder3d.texture(wonder3d.reconstruct(views, preset="fast"), views, size=512)
    tm = textured.to_trimesh()
    assert tm.visual.kind == "texture"
    assert tm.visual.material.image.size == (512, 512)
    assert np.array_equal(tm.visual.uv, textured.uvs.astype(np.float64))


def test_viewset_arrays_round_trip(spot_views_dir):
    views = wonder3d.ViewSet.load(spot_views_dir)
    assert len(views) == 6 and views.width == 128 and views.rig == "wonder3d_ortho"
    normals, masks, colours = views.normals, views.masks, views.colours
    assert normals.shape == (6, 128, 128, 3) and masks.shape == (6, 128, 128) and colours.shape == (6, 128, 128, 3)
    again = wonder3d.ViewSet.from_arrays(normals, masks, colours, rig="wonder3d-ortho")
    assert np.array_equal(again.normals, normals) and np.array_equal(again.masks, masks)
    assert np.array_equal(again.colours, colours)
    # A list of per-view arrays works too.
    listed = wonder3d.ViewSet.from_arrays(list(normals), list(masks[..., None]))
    assert np.array_equal(listed.masks, masks) and listed.colours is None


# Every error class from a bad input: the class, its built-in base and the message.


def test_missing_file_is_a_file_error(tmp_path):
    missing = tmp_path / "missing.obj"
    with pytest.raises(wonder3d.FileError) as info:
        wonder3d.Mesh.load(missing)
    assert isinstance(info.value, OSError) and isinstance(info.value, wonder3d.Error)
    assert info.value.errno == errno.ENOENT and info.value.filename == str(missing)
    assert str(missing) in str(info.value)
    with pytest.raises(wonder3d.FileError):
        wonder3d.ViewSet.load(tmp_path / "no_views")


def test_bad_file_contents_are_a_format_error(tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999999999\nend_header\n")
    with pytest.raises(wonder3d.FormatError) as info:
        wonder3d.Mesh.load(bad)
    assert isinstance(info.value, ValueError) and str(bad) in str(info.value)
    with pytest.raises(wonder3d.FormatError, match="extension"):
        wonder3d.Mesh.load(tmp_path / "mesh.xyz")


@pytest.mark.parametrize(
    "vertices, faces, message",
    [
        (np.zeros((4, 2), np.float32), [[0, 1, 2]], r"vertices: expected a float array of shape \(N, 3\), got a float32 array of shape \(4, 2\)"),
        (np.zeros((4, 3), np.int32), [[0, 1, 2]], r"vertices: expected a float array"),
        (np.zeros((4, 3), np.float32), np.zeros((1, 3), np.float32), r"faces: expected an integer array of shape \(M, 3\)"),
        (np.zeros((4, 3), np.float32), [[0, 1, 2, 3]], r"faces: expected an integer array of shape \(M, 3\)"),
        (np.zeros((4, 3), np.float32), [[0, 1, 4]], r"faces\[0\]\[2\]: expected a vertex index in 0\.\.4, got 4"),
        (np.zeros((4, 3), np.float32), [[0, -1, 2]], r"faces\[0\]\[1\]: expected a vertex index in 0\.\.4, got -1"),
        (np.array([[0, 0, 0], [1, np.nan, 0], [0, 1, 0]], np.float32), [[0, 1, 2]], r"positions\[1\]\.y"),
        ("not an array", [[0, 1, 2]], r"vertices: expected"),
    ],
)
def test_bad_arrays_are_invalid_input_errors(vertices, faces, message):
    with pytest.raises(wonder3d.InvalidInputError, match=message) as info:
        wonder3d.Mesh(vertices, faces)
    assert isinstance(info.value, ValueError) and isinstance(info.value, wonder3d.Error)


def test_bad_rig_and_preset_names(spot_views_dir):
    spot = wonder3d.Mesh.load(SPOT)
    with pytest.raises(wonder3d.InvalidInputError, match="rig: expected one of wonder3d-ortho"):
        wonder3d.render_views(spot, rig="octahedron")
    with pytest.raises(wonder3d.InvalidInputError, match="size"):
        wonder3d.render_views(spot, size=0)
    views = wonder3d.ViewSet.load(spot_views_dir)
    with pytest.raises(wonder3d.InvalidInputError, match="preset"):
        wonder3d.reconstruct(views, preset="fastest")
    with pytest.raises(wonder3d.InvalidInputError, match="masks"):
        wonder3d.ViewSet.from_arrays(views.normals, views.masks[:5])
    with pytest.raises(wonder3d.InvalidInputError, match=r"normals\[0\]"):
        wonder3d.ViewSet.from_arrays(views.normals[:, :, :, :2], views.masks)
