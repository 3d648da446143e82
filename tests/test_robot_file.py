"""Robot-file loading and validation (SPEC §3)."""

import dataclasses
import tomllib

import numpy as np
import pytest

from conftest import PROTOTYPE, ROOT
from tendonsense.forward import solve
from tendonsense.robot import (Mass, RobotFileError, fitted_toml, load_robot, parse_robot,
                               robot_to_toml)

TEXT = PROTOTYPE.read_text()


def bad(tmp_path, old, new):
    p = tmp_path / "r.toml"
    assert old in TEXT
    p.write_text(TEXT.replace(old, new, 1))
    with pytest.raises(RobotFileError) as e:
        load_robot(p)
    msg = str(e.value)
    assert "\n" not in msg
    return msg


@pytest.mark.parametrize("old,new,expect", [
    ("length = 0.25", "length = -0.25", "rod.length"),
    ("length = 0.25", "length = nan", "finite"),
    ("length = 0.25", "length = 250", "lengths are in metres"),  # mm typed
    ("radius = [0.0125, 0.005]", "radius = [12.5, 5]", "lengths are in metres"),
    ("radius = [0.0125, 0.005]", "radius = [0.0125, -0.005]", "got -0.005"),
    ("young_modulus = 1.0e6", "young_modulus = 'soft'", "rod.young_modulus"),
    ("young_modulus = 1.0e6", "young_modulus = -1.0e6", "rod.young_modulus: must be > 0"),
    ("young_modulus = 1.0e6", "young_modulus = 2.5", "Young's modulus is in Pa"),  # MPa
    ("young_modulus = 1.0e6", "young_modulus = 200", "Young's modulus is in Pa"),  # GPa
    ("density = 1340.0", "density = 1.34", "densities are in kg/m³"),  # g/cm³
    ("poisson_ratio = 0.5", "poisson_ratio = 0.7", "rod.poisson_ratio: must be in (-1, 0.5]"),
    ("friction = 0.4", "friction = 40", "not a percentage"),
    ("acceleration = [0.0, 0.0, -9.81]", "acceleration = [0.0, 0.0, -9810]", "are in m/s²"),
    ("density = 1340.0", "density = 1340.0\ncolour = 'red'", "unknown key"),
    ("disks = 9", "disks = [0.0, 0.1, 0.05, 0.25]", "strictly increasing"),
    ("offset_base = [0, 0.014]", "offset_base = [0, 0.04]", "reachable radius"),
    ("bending_y = 4", "bending_y = -1", "strain.bending_y"),
    ('name = "mid"', 'name = "tip"', "two markers"),
    ("X = 0.125", "X = 0.3", "marker[0] (mid).X"),
    ("friction = 0.4", "friction = -0.4", "tendon[0] (t1).friction: must be >= 0, got -0.4"),
    ("length = 0.25", "length = true", "got true"),  # as TOML spells it
    ("length = 0.25\nradius = [0.0125, 0.005]",
     "length = 250\nradius = [[0, 0.0125], [0.25, 0.005]]", "lengths are in metres"),
    ("disks = 9", "disks = [0.0, 0.1, 0.3]", "got 0.3"),
    ("[gravity]\nacceleration = [0.0, 0.0, -9.81]", "[gravity]\nacceleration = [0.0, -9.81]",
     "gravity.acceleration"),
])
def test_bad_values_name_key_and_reason(tmp_path, old, new, expect):
    assert expect in bad(tmp_path, old, new)


def test_material_at_its_bounds_is_taken(tmp_path):
    """No gravity (density 0) and the softest and lightest material a rod may have."""
    for old, new in (("density = 1340.0", "density = 0.0"), ("density = 1340.0", "density = 10"),
                     ("young_modulus = 1.0e6", "young_modulus = 1000")):
        p = tmp_path / "robot.toml"
        p.write_text(PROTOTYPE.read_text().replace(old, new))
        load_robot(p)


def test_missing_key(tmp_path):
    assert "rod.young_modulus: missing" in bad(tmp_path, "young_modulus = 1.0e6\n", "")


def test_bad_rotation():
    with pytest.raises(RobotFileError, match="base.rotation"):
        parse_robot({"rod": {"length": 1, "radius": [0.1, 0.1], "young_modulus": 1e6,
                             "poisson_ratio": 0.3, "density": 1000},
                     "base": {"rotation": [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}})


def test_round_trip_through_toml(prototype, tmp_path):
    p = tmp_path / "again.toml"
    p.write_text(robot_to_toml(prototype))
    assert load_robot(p) == prototype


def test_soromox_tentacle_loads_and_hangs():
    """Piecewise radius, base rotation and off-centre markers (second robot)."""
    robot = load_robot(ROOT / "examples" / "soromox_tentacle.toml")
    assert len(robot.rod.radius_knots) == 3
    assert robot.tendons[0].disks[-1] == pytest.approx(0.305)
    res = solve(robot)
    assert res.converged
    # hanging straight down under gravity: the tip marker sits at its offset below the base
    tip = res.markers["m4"]
    assert tip[2] < -0.35 and abs(tip[1]) < 1e-9
    np.testing.assert_allclose(res.backbone[-1][:2], [0, 0], atol=1e-9)
    pulled = solve(robot, {"t1": 3.08})
    assert pulled.converged
    assert np.linalg.norm(pulled.markers["m4"] - tip) > 0.02


def test_elements_in_the_strain_table(tmp_path):
    from tendonsense.forward import model_for
    text = PROTOTYPE.read_text()
    assert "[strain]" in text
    with_elements = text.replace("[strain]", '[strain]\nelements = "disks"')
    path = tmp_path / "r.toml"
    path.write_text(with_elements)
    robot = load_robot(path)
    assert robot.elements == pytest.approx(tuple(np.linspace(0, 0.25, 9)[1:-1]))
    model = model_for(robot)
    assert model.structure.n_elements == 8
    assert model.nq == 8 * sum(d + 1 for _, d in robot.strain)
    nodes = np.asarray(model.values.nodes)
    for x in robot.elements:  # no Magnus interval straddles an element boundary
        assert np.min(np.abs(nodes - x)) < 1e-12
    path.write_text(robot_to_toml(robot))
    assert load_robot(path).elements == robot.elements
    for bad, why in (("[0.1, 0.05]", "increasing"), ("[0.0, 0.1]", "strictly inside"),
                     ('"rings"', "disks")):
        path.write_text(text.replace("[strain]", f"[strain]\nelements = {bad}"))
        with pytest.raises(RobotFileError, match=why):
            load_robot(path)


MASS = '\n[[mass]]\nname = "ring"\nX = 0.15\nmass = 0.02\n'


@pytest.mark.parametrize("table,expect", [
    ('\n[[mass]]\nname = "ring"\nX = 0.3\nmass = 0.02\n', "mass[0] (ring).X"),
    ('\n[[mass]]\nname = "ring"\nX = 0.1\nmass = 0.0\n', "mass[0] (ring).mass"),
    ('\n[[mass]]\nname = "ring"\nX = 0.1\n', "mass[0] (ring).mass: missing"),
    ('\n[[mass]]\nname = "ring"\nX = 0.1\nmass = 0.01\noffset = [0, 1]\n', "mass[0] (ring).offset"),
    (MASS + MASS, "two masses"),
])
def test_bad_masses_name_key_and_reason(tmp_path, table, expect):
    p = tmp_path / "r.toml"
    p.write_text(TEXT + table)
    with pytest.raises(RobotFileError) as e:
        load_robot(p)
    assert expect in str(e.value)


def test_lumped_masses_are_their_weights_as_point_forces(prototype, tmp_path):
    """Issue 11: a rigid lumped mass gives the same result as the equivalent point force (to
    1e-9 m); an offset mass adds the moment of its weight about the centre line."""
    p = tmp_path / "r.toml"
    p.write_text(TEXT + MASS + '\n[[mass]]\nname = "tip sensor"\nX = 0.25\nmass = 0.005\n')
    robot = load_robot(p)
    assert load_robot(p) == robot and len(robot.masses) == 2
    again = tmp_path / "again.toml"
    again.write_text(robot_to_toml(robot))
    assert load_robot(again) == robot
    g = np.array(robot.gravity)
    T = {"t1": 1.0, "t3": 0.5}
    with_masses = solve(robot, T, [(0.07, (0.0, 0.1, 0.0))])
    as_forces = solve(prototype, T, [(0.07, (0.0, 0.1, 0.0)), (0.15, tuple(0.02 * g)),
                                     (0.25, tuple(0.005 * g))])
    assert with_masses.converged and as_forces.converged
    for k in with_masses.markers:
        assert np.linalg.norm(with_masses.markers[k] - as_forces.markers[k]) < 1e-9
    for k in with_masses.displacements:
        assert abs(with_masses.displacements[k] - as_forces.displacements[k]) < 1e-9
    plain = solve(prototype, T, [(0.07, (0.0, 0.1, 0.0))])
    assert np.linalg.norm(plain.markers["tip"] - with_masses.markers["tip"]) > 1e-3
    # small deflections (a stiff rod): the weight of a mass 2 cm above the centre line acts
    # as at its X; 2 cm ahead of it, nearly as a point force 2 cm further out (less the
    # bending of those 2 cm, which the couple of the offset weight does not load)
    stiff = prototype.with_parameters(young_modulus=1e9)
    sag = {}
    for name, X, offset in (("above", 0.15, (0.0, 0.0, 0.02)), ("ahead", 0.15, (0.02, 0.0, 0.0)),
                            ("at 0.15", 0.15, None), ("at 0.17", 0.17, None)):
        if offset is None:
            res = solve(stiff, {}, [(X, tuple(0.02 * g))])
        else:
            res = solve(stiff.replace(masses=(Mass("ring", X, 0.02, offset),)), {})
        sag[name] = res.markers["tip"] - solve(stiff, {}).markers["tip"]
    assert np.linalg.norm(sag["above"] - sag["at 0.15"]) < 1e-3 * np.linalg.norm(sag["at 0.15"])
    assert np.linalg.norm(sag["ahead"] - sag["at 0.17"]) < 0.05 * np.linalg.norm(sag["at 0.17"])
    assert np.linalg.norm(sag["ahead"]) < np.linalg.norm(sag["at 0.17"])
    assert np.linalg.norm(sag["ahead"] - sag["at 0.15"]) > 0.1 * np.linalg.norm(sag["at 0.15"])


# ----------------------------------------------------------------------------- fitted files

GUESS = ROOT / "examples" / "tutorial" / "robot_guess.toml"
HEADER = ["fitted by tendonsense identify 0.1.0 on 2026-12-01 20:40 UTC",
          "from examples/tutorial/snapshots.csv (12 snapshots); robot file "
          "examples/tutorial/robot_guess.toml",
          "parameters fitted: young_modulus = 1.02e6 Pa, density = 1333 kg/m³",
          "marker RMSE 0.41 mm (before the fit 6.2 mm)"]
HEADER_LINES = ["# " + h for h in HEADER] + [""]


def fitted_from(robot, E=1023456.7, rho=1333.25, mu=None):
    """A "fitted" robot: ``robot`` with other E, ρ and the per-tendon μ of ``mu``."""
    mu = mu or {}
    tendons = tuple(dataclasses.replace(t, friction=mu.get(t.name, t.friction))
                    for t in robot.tendons)
    rod = dataclasses.replace(robot.rod, young_modulus=E, density=rho)
    return dataclasses.replace(robot, rod=rod, tendons=tendons)


def body(out):
    """The lines after the header and its blank line."""
    lines = out.split("\n")
    assert lines[:len(HEADER_LINES)] == HEADER_LINES
    return lines[len(HEADER_LINES):]


def test_fitted_file_keeps_comments_blank_lines_and_other_keys():
    text = GUESS.read_text()
    fitted = fitted_from(load_robot(GUESS), mu={"t2": 0.35})
    out = body(fitted_toml(text, fitted, HEADER))
    original = text.split("\n")
    assert len(out) == len(original)  # nothing added, nothing lost, same order
    changed = [i for i, (a, b) in enumerate(zip(original, out)) if a != b]
    assert [original[i].split("=")[0].strip() for i in changed] == [
        "young_modulus", "density", "friction"]
    assert out[changed[2] - 3] == 'name = "t2"'  # the friction of t2, not of t1 or t3
    for a, b in zip(original, out):
        if not a.strip() or a.startswith("#"):
            assert a == b
    assert out[:2] == original[:2] and original[0].startswith("# The tutorial robot")


def test_fitted_file_keeps_the_trailing_comment_of_a_rewritten_line():
    text = PROTOTYPE.read_text().replace("density = 1340.0\n", "density = 1340.0  # kg/m^3\n")
    out = fitted_toml(text, fitted_from(load_robot(PROTOTYPE)), HEADER)
    assert "\ndensity = 1333.25  # kg/m^3\n" in out
    # aligned comments stay aligned: the tutorial's two comments keep their column
    out = fitted_toml(GUESS.read_text(), fitted_from(load_robot(GUESS)), HEADER)
    assert "\nyoung_modulus = 1023456.7       # Pa\n" in out
    assert "\ndensity = 1333.25               # kg/m^3\n" in out


@pytest.mark.parametrize("path", [GUESS, PROTOTYPE])
def test_fitted_file_round_trips_through_load_robot(tmp_path, path):
    robot = load_robot(path)
    fitted = fitted_from(robot, E=987654.321, rho=1111.125, mu={"t1": 0.125, "t3": 0.6})
    assert fitted != robot
    p = tmp_path / path.name  # the same stem: the same default name
    p.write_text(fitted_toml(path.read_text(), fitted, HEADER))
    again = load_robot(p)
    assert again.rod.young_modulus == 987654.321 and again.rod.density == 1111.125
    assert {t.name: t.friction for t in again.tendons} == {
        t.name: t.friction for t in fitted.tendons}
    assert again == fitted  # and every other value as loaded from the original


def test_fitted_file_adds_a_missing_friction_to_its_tendon(tmp_path):
    text = PROTOTYPE.read_text()
    block = 'name = "t2"\noffset_base = [-0.01212435565, -0.007]\n' \
            'offset_tip = [-0.005629165125, -0.00325]\nfriction = 0.4\ndisks = 9\n'
    assert text.count(block) == 1
    text = text.replace(block, block.replace("friction = 0.4\n", ""))
    p = tmp_path / "paper_prototype.toml"
    p.write_text(text)
    robot = load_robot(p)
    assert robot.tendons[1].friction == 0.0  # the default
    out = fitted_toml(text, fitted_from(robot, mu={"t2": 0.25}), HEADER)
    assert block.replace("friction = 0.4\ndisks = 9\n", "disks = 9\nfriction = 0.25\n") in out
    assert out.count("friction = ") == 3
    p.write_text(out)
    assert [t.friction for t in load_robot(p).tendons] == [0.4, 0.25, 0.4]
    # at the default it needs no line
    assert fitted_toml(text, robot, HEADER).count("friction = ") == 2


def test_fitted_file_adds_a_missing_rod_key_after_the_tables_last_key():
    text = PROTOTYPE.read_text().replace("density = 1340.0\n", "")
    robot = load_robot(PROTOTYPE)
    out = fitted_toml(text, fitted_from(robot), HEADER)
    assert "poisson_ratio = 0.5\ndensity = 1333.25\n\n[strain]" in out
    assert tomllib.loads(out)["rod"]["density"] == 1333.25


def test_a_second_fit_replaces_the_header():
    robot = load_robot(GUESS)
    first = fitted_toml(GUESS.read_text(), fitted_from(robot), HEADER)
    header2 = ["fitted by tendonsense identify 0.1.0 on 2026-12-02 09:00 UTC", "second fit"]
    second = fitted_toml(first, fitted_from(robot, E=2e6), header2)
    assert second.count("fitted by tendonsense identify") == 1
    assert second.startswith("# fitted by tendonsense identify 0.1.0 on 2026-12-02 09:00 UTC\n"
                             "# second fit\n\n# The tutorial robot")
    assert "young_modulus = 2000000.0       # Pa" in second
    # below the header: the first fit's file, but for E
    assert [ln for ln in second.split("\n")[3:] if "young_modulus" not in ln] == [
        ln for ln in first.split("\n")[5:] if "young_modulus" not in ln]


def test_untouched_keys_are_byte_identical_and_spacing_is_tolerated(tmp_path):
    text = (PROTOTYPE.read_text().replace("young_modulus = 1.0e6", "young_modulus=1e6")
            .replace("density = 1340.0", "  density   =  1340   # kg/m^3"))
    p = tmp_path / "paper_prototype.toml"
    p.write_text(text)
    robot = load_robot(p)
    out = fitted_toml(text, fitted_from(robot, E=1.5e6, rho=1250.5), HEADER)
    assert "\nyoung_modulus=1500000.0\n" in out
    assert "\n  density   =  1250.5  # kg/m^3\n" in out  # the comment at its column
    assert out.endswith(text.split("density   =  1340   # kg/m^3\n")[1])
    # a value the fit left as it was keeps its spelling
    same = fitted_toml(text, robot, HEADER)
    assert same == "\n".join(HEADER_LINES) + "\n" + text
    p.write_text(out)
    assert load_robot(p) == fitted_from(robot, E=1.5e6, rho=1250.5)


def test_fitted_file_needs_the_files_tendons():
    robot = load_robot(PROTOTYPE)
    other = dataclasses.replace(robot, tendons=robot.tendons[:2])
    with pytest.raises(RobotFileError, match="tendons"):
        fitted_toml(PROTOTYPE.read_text(), other, HEADER)


def test_the_thinnest_section_a_tendon_spans():
    """A tension is bounded by E·A where the rod is thinnest between its base and the tendon's
    anchor: a knot inside the span, an anchor before the knot, a continuous tendon."""
    import math

    from conftest import robot_from
    from tendonsense.inputs import tension_error, thinnest_sections
    robot = robot_from(
        rod={"length": 0.25, "radius": [[0.0, 0.01], [0.1, 0.004], [0.25, 0.006]],
             "young_modulus": 1e6, "poisson_ratio": 0.5, "density": 1000.0},
        tendon=[{"name": "short", "offset_base": [0, 0.003], "offset_tip": [0, 0.003],
                 "disks": [0.0, 0.025, 0.05]},
                {"name": "long", "offset_base": [0, 0.003], "offset_tip": [0, 0.003],
                 "disks": [0.0, 0.1, 0.2]},
                {"name": "along", "offset_base": [0, 0.003], "offset_tip": [0, 0.003],
                 "disks": "continuous"}])
    area = thinnest_sections(robot)
    assert area["short"] == pytest.approx(math.pi * 0.007 ** 2)  # r(0.05), before the knot
    assert area["long"] == area["along"] == pytest.approx(math.pi * 0.004 ** 2)  # the knot
    limit = 0.5 * 1e6 * math.pi * 0.004 ** 2
    assert tension_error(robot, "long", 0.99 * limit) is None
    assert "tensions are in newtons" in tension_error(robot, "long", 1.01 * limit)
    assert tension_error(robot, "long", 1.01 * limit, young_modulus=math.inf) is None


def test_a_robot_hashes_as_its_fields_and_is_sent_without_its_hash(prototype):
    """A robot's hash is kept (it keys the caches a reading consults) but stays that of its
    fields: an equal copy hashes alike, another value does not, and a pickle (a Dask task)
    carries no hash of the sending process (str hashes are per process)."""
    import pickle
    fields = tuple(getattr(prototype, f.name) for f in dataclasses.fields(prototype))
    assert hash(prototype) == hash(fields) == hash(prototype.replace())
    other = prototype.with_parameters(young_modulus=2 * prototype.rod.young_modulus)
    assert other != prototype and hash(other) != hash(prototype)
    sent = pickle.loads(pickle.dumps(prototype))
    assert "_hash" not in sent.__dict__ and sent == prototype
    assert hash(sent) == hash(prototype)


def test_a_dangling_link_is_named(tmp_path):
    """examples/ copied without -L leaves links to ../src/… that lead nowhere: the message
    says so, not only "No such file or directory"."""
    link = tmp_path / "paper_prototype.toml"
    link.symlink_to("../src/tendonsense/data/paper_prototype.toml")
    with pytest.raises(RobotFileError, match="a symbolic link to ../src/tendonsense/data/paper_"
                                             "prototype.toml, which does not exist: a folder "
                                             "copied with `cp -r` keeps its links; `cp -rL` "
                                             r"copies the files\)$"):
        load_robot(link)
    with pytest.raises(RobotFileError, match=r"cannot read robot file \(No such file"):
        load_robot(tmp_path / "missing.toml")
