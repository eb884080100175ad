"""The ``constraints`` option: positive node set (default) vs the equispaced lattice of [CAMWA21]."""
import numpy as np
import pytest
from ngsolve import H1, LinearForm, dx

from ngcontact import CrissCrossSquare
from ngcontact.cli import main
from ngcontact.discretizations import DISCRETIZATIONS, FEMDiscretization
from ngcontact.discretizations.lagrange import LagrangeNodes
from ngcontact.discretizations.nodesets import cardinal_weights, reference_nodes
from ngcontact.drivers import RunOptions, run_scene
from ngcontact.scenes import load_scene


def test_option_is_validated_and_named():
    assert RunOptions().constraints == "nodal"
    assert RunOptions(constraints="equispaced").constraints == "equispaced"
    with pytest.raises(ValueError, match=r"option constraints must be one of \['bernstein', 'equispaced', 'nodal'\], "
                                         r"got 'gauss'"):
        RunOptions(constraints="gauss")
    with pytest.raises(ValueError, match=r"option constraints must be one of \['equispaced', 'nodal'\] for disc 'hho'"):
        RunOptions(disc="hho", constraints="bernstein")
    with pytest.raises(ValueError, match="option constraints must be one of"):
        FEMDiscretization(load_scene("test1").problem, CrissCrossSquare().mesh(0), order=2, constraints=None)


def test_cli_flag_and_help(capsys):
    assert main(["run", "--help"]) == 0
    assert "--constraints {nodal,equispaced,bernstein}" in capsys.readouterr().out
    assert main(["run", "test1", "--constraints", "lattice"]) == 2
    assert "--constraints" in capsys.readouterr().err
    assert main(["run", "test1", "--disc", "sipg", "--constraints", "bernstein"]) == 2
    assert "option --constraints must be one of ['equispaced', 'nodal'] for disc 'sipg'" in capsys.readouterr().err


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_integrals_of_the_nodal_basis_on_a_mesh(p):
    """(psi_l, 1) of the global Lagrange basis (the lumped constraint weights): none negative with the
    positive set; the equispaced P4 lattice has negative ones (its edge midpoints).  P1-P3: one node set."""
    mesh = CrissCrossSquare().mesh(1)
    fes = H1(mesh, order=p)
    ones = LinearForm(fes.TestFunction() * dx).Assemble().vec.FV().NumPy()
    w = {k: LagrangeNodes.build(fes, k).T.T @ ones for k in ("positive", "equispaced")}
    assert w["positive"].min() > -1e-15
    if p == 4:
        assert w["equispaced"].min() < -1e-4
    else:
        np.testing.assert_array_equal(w["positive"], w["equispaced"])


@pytest.mark.parametrize("disc", ["fem", "hho", "sipg"])
@pytest.mark.parametrize("p", [3, 4])
def test_discretizations_put_their_constraints_on_the_chosen_nodes(disc, p):
    problem = load_scene("test1").problem
    mesh = CrissCrossSquare().mesh(0)
    pts = {c: DISCRETIZATIONS[disc](problem, mesh, order=p, constraints=c).constraint_points
           for c in ("nodal", "equispaced")}
    same = pts["nodal"].shape == pts["equispaced"].shape and np.array_equal(pts["nodal"], pts["equispaced"])
    assert same == (p == 3)
    if disc != "fem":
        basis = DISCRETIZATIONS[disc](problem, mesh, order=p).basis
        np.testing.assert_array_equal(basis.ref_nodes, reference_nodes(p, "positive")[:, :2])
        # the cell basis integrates to the node set's weights (reference triangle: |K| = 1/2)
        np.testing.assert_allclose(2 * basis.mass_ref.sum(axis=1), cardinal_weights(reference_nodes(p, "positive")),
                                   rtol=0, atol=1e-12)


def test_p4_positive_nodes_beat_the_equispaced_lattice():
    """test 1, FEM P4, nested T0-T2: the positive set keeps rate ~4 on T1 -> T2, the lattice loses it
    (results/fem/CONSTRAINTS.md continues both to T4).  The lattice's errors are those of
    results/fem/TABLES.md (4 digits)."""
    scene = load_scene("test1")
    err = {}
    for c in ("nodal", "equispaced"):
        res = run_scene(scene, RunOptions.for_scene(scene, order=4, levels=3, constraints=c))
        err[c] = np.array([row["err_energy"] for row in res.rows])
    np.testing.assert_allclose(err["equispaced"], [1.468e-4, 1.038e-5, 9.594e-7], rtol=5e-4)
    rate = {c: np.log2(e[1] / e[2]) for c, e in err.items()}
    assert rate["nodal"] > 3.9 and rate["equispaced"] < 3.6
    assert err["nodal"][2] < 0.75 * err["equispaced"][2]


def test_report_reads_runs_and_computes_the_node_set_table(tmp_path):
    from ngcontact.studies.constraints import main as report

    dirs = []
    for c in ("nodal", "equispaced"):
        d = tmp_path / f"test1-fem-p4-{c}"
        assert main(["run", "test1", "--order", "4", "--levels", "2", "--constraints", c, "--out", str(d), "-q",
                     "--no-vtk", "--no-plots"]) == 0
        dirs.append(str(d))
    out = tmp_path / "CONSTRAINTS.md"
    assert report([str(out), *dirs]) == 0
    text = out.read_text()
    assert "| 4 | equispaced | 0.0000 | -0.0222, 0.0889 | 0.1778 | -0.0222 **<0** | 3.47 |" in text
    assert "| 4 | positive | 0.0122 | 0.0181, 0.0533 | 0.2315 | 0.0122 | 2.94 |" in text
    assert "| FEM | 4 | equispaced lattice | 1.468e-04 | 1.038e-05 |" in text
    assert "| FEM | 4 | positive nodes (nodal) | 1.540e-04 | 1.058e-05 |" in text
    assert "| test 1 FEM P4 to T4 |  | not run | - |" in text
