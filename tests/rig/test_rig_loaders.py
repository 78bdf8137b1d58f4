"""OBJ/PLY meshes, TGF skeletons and DMAT weights: round trips against libigl's writers, and
errors that name the file and the line or field."""

import igl
import numpy as np
import pytest

from puppet.rig import RigError, load_rig
from puppet.rig.mesh_io import read_mesh, read_obj, read_ply
from puppet.rig.tgf_dmat import read_dmat, read_tgf, write_dmat


@pytest.fixture
def mesh():
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]], float)
    F = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    return V, F


@pytest.mark.parametrize("encoding", ["Binary", "Ascii"])
def test_ply_written_by_libigl_reads_back(tmp_path, mesh, encoding):
    V, F = mesh
    path = tmp_path / "m.ply"
    igl.writePLY(str(path), V, F, encoding=getattr(igl.FileEncoding, encoding))
    V2, F2 = read_ply(path)
    np.testing.assert_allclose(V2, V)
    np.testing.assert_array_equal(F2, F)
    assert F2.dtype == np.int32


def test_obj_with_quads_negative_indices_and_slashes(tmp_path):
    path = tmp_path / "q.obj"
    path.write_text("# quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\n"
                    "v 2 0 0\nf -1 2 3\n")
    V, F = read_obj(path)
    assert V.shape == (5, 3)
    np.testing.assert_array_equal(F, [[0, 1, 2], [0, 2, 3], [4, 1, 2]])


def test_obj_written_by_libigl_reads_back(tmp_path, mesh):
    V, F = mesh
    igl.writeOBJ(str(tmp_path / "m.obj"), V, F)
    V2, F2 = read_obj(tmp_path / "m.obj")
    np.testing.assert_allclose(V2, V)
    np.testing.assert_array_equal(F2, F)


def test_mesh_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    with pytest.raises(RigError, match=r"bad.obj:3: f: face references a vertex not yet defined"):
        read_obj(bad)
    bad.write_text("v 0 zero 0\n")
    with pytest.raises(RigError, match=r"bad.obj:1: v: bad vertex"):
        read_obj(bad)
    ply = tmp_path / "bad.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                   "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0\n")
    with pytest.raises(RigError, match=r"bad.ply: vertex: vertex element has no 'z' property"):
        read_ply(ply)
    with pytest.raises(RigError, match=r"m.stl: unknown mesh format"):
        read_mesh(tmp_path / "m.stl")
    with pytest.raises(RigError, match="file not found"):
        read_obj(tmp_path / "missing.obj")


def test_tgf_is_one_based_with_point_handles_and_any_edge_order(tmp_path):
    # Joints 1..5; edges listed child first; joint 5 is a point handle.
    (tmp_path / "s.tgf").write_text("1 0 0 0\n2 0 1 0\n3 0 2 0\n4 1 1 0\n5 3 3 3\n#\n2 3 1 0 0\n1 2 1 0 0\n"
                                    "2 4\n3 4 0 0 1\n")
    sk, columns = read_tgf(tmp_path / "s.tgf")
    # bones: bone1 = 2->3, bone2 = 1->2 (root), bone3 = 2->4; point5; cage edge 3-4 ignored.
    assert sorted(sk.names) == ["bone1", "bone2", "bone3", "point5"]
    i = {n: sk.index(n) for n in sk.names}
    assert sk.parents[i["bone2"]] == -1
    assert sk.parents[i["bone1"]] == i["bone2"]
    assert sk.parents[i["bone3"]] == i["bone2"]
    assert sk.parents[i["point5"]] == -1
    np.testing.assert_allclose(sk.heads[i["bone1"]], [0, 1, 0])
    np.testing.assert_allclose(sk.tails[i["bone3"]], [1, 1, 0])
    np.testing.assert_allclose(sk.heads[i["point5"]], sk.tails[i["point5"]])
    # libigl columns: [point5, bone1, bone2, bone3]
    assert {n: int(columns[i[n]]) for n in sk.names} == {"point5": 0, "bone1": 1, "bone2": 2, "bone3": 3}
    for a in range(sk.bone_count):
        assert sk.parents[a] < a


def test_tgf_errors_name_the_line(tmp_path):
    path = tmp_path / "bad.tgf"
    path.write_text("1 0 0 0\n2 0 1 0\n#\n0 1\n")
    with pytest.raises(RigError, match=r"bad.tgf:4: edge: edge references joint 0.*1-based"):
        read_tgf(path)
    path.write_text("1 0 0\n#\n")
    with pytest.raises(RigError, match=r"bad.tgf:1: joint: cannot parse"):
        read_tgf(path)


@pytest.mark.parametrize("ascii_format", [True, False])
def test_dmat_written_by_libigl_reads_back(tmp_path, ascii_format):
    W = np.random.default_rng(3).random((7, 4))
    igl.writeDMAT(str(tmp_path / "w.dmat"), W, ascii_format)
    np.testing.assert_allclose(read_dmat(tmp_path / "w.dmat"), W, rtol=1e-12)


def test_dmat_written_by_us_reads_in_libigl(tmp_path):
    W = np.random.default_rng(4).random((5, 3))
    write_dmat(tmp_path / "w.dmat", W)
    np.testing.assert_allclose(igl.readDMAT(str(tmp_path / "w.dmat")), W, rtol=1e-12)


def test_dmat_errors(tmp_path):
    path = tmp_path / "bad.dmat"
    path.write_text("2 3\n1\n2\n3\n")
    with pytest.raises(RigError, match=r"bad.dmat: data: 3 entries, header says 3 rows x 2 columns"):
        read_dmat(path)


def test_rig_from_obj_tgf_dmat_matches_files(tube_rig_dir):
    rig = load_rig(tube_rig_dir / "tube.toml")
    assert rig.skeleton.names == ("bone1", "bone2", "bone3")
    assert rig.solver_options.clusters == 12 and rig.solver_options.energy == "spokes"
    assert rig.check_weights().ok
    np.testing.assert_allclose(rig.W, read_dmat(tube_rig_dir / "tube.dmat"), atol=1e-12)


def test_weights_with_wrong_row_count_name_the_file(tube_rig_dir):
    write_dmat(tube_rig_dir / "tube.dmat", np.ones((3, 3)))
    with pytest.raises(RigError, match=r"tube.dmat: weights: 3 rows x 3 columns, mesh has \d+ vertices"):
        load_rig(tube_rig_dir / "tube.toml")
