"""The model YAML's ``model.urdf``: read relative to the YAML, its joints the configuration's,
refused beside M and gravity, written back relative to where the configuration is saved."""
import shutil

import numpy as np
import pytest
import yaml

from sea_daemon.core.config import ModelConfig
from sea_daemon.errors import ConfigError, InputError
from sea_daemon.io.configfile import load_config, save_config
from tests._paths import repo_root

CONFIGS = repo_root() / "configs"


@pytest.fixture
def arm(tmp_path):
    """A copy of the 2-DoF example (YAML and URDF) in a folder of its own."""
    shutil.copy(CONFIGS / "exo_2dof.yaml", tmp_path / "arm.yaml")
    shutil.copy(CONFIGS / "exo_2dof_arm.urdf", tmp_path / "exo_2dof_arm.urdf")
    return tmp_path / "arm.yaml"


def edit(path, **model):
    d = yaml.safe_load(path.read_text())
    for k, v in model.items():
        if v is None:
            d["model"].pop(k, None)
        else:
            d["model"][k] = v
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


def test_the_example_loads_with_its_rigid_body():
    cfg = load_config(CONFIGS / "exo_2dof.yaml")
    assert cfg.joints == 2 and cfg.model.urdf == "exo_2dof_arm.urdf"
    assert cfg.model.rigid.joint_names == ("shoulder", "elbow")
    np.testing.assert_allclose(cfg.model.M, cfg.model.rigid.mass_matrix(np.zeros(2)))
    assert not np.any(cfg.model.gravity)
    np.testing.assert_array_equal(np.diag(cfg.model.K_s), [300.0, 150.0])
    # the wearer's arm (fixed joints) is part of the body: at 90° shoulder flexion g(q) holds both arms
    assert cfg.model.rigid.gravity(np.array([np.pi / 2, 0.0]))[0] == pytest.approx(16.3, abs=0.1)


@pytest.mark.parametrize("model,message", [
    ({"M": [0.5, 0.1]}, "model.M: not allowed with model.urdf"),
    ({"gravity": [1.0, 2.0]}, "model.gravity: not allowed with model.urdf"),
    ({"urdf": 3}, "model.urdf: must be the path of a URDF file"),
    ({"urdf": "missing.urdf"}, "missing.urdf"),
])
def test_refused_urdf_settings_name_the_key(arm, model, message):
    with pytest.raises(InputError, match=message):
        load_config(edit(arm, **model))


def test_the_urdf_must_have_the_configurations_joints(arm):
    d = yaml.safe_load(arm.read_text())
    d["joints"] = 1
    for k in ("J", "D_m", "K_s", "D_s"):
        d["model"][k] = d["model"][k][0]
    d.pop("estimator")
    arm.write_text(yaml.safe_dump(d))
    with pytest.raises(ConfigError, match=r"model.urdf: 'exo_2dof_arm.urdf' has 2 movable joint\(s\) "
                                          r"\(shoulder, elbow\); joints is 1"):
        load_config(arm)


def test_a_urdf_not_read_is_refused_not_ignored():
    d = yaml.safe_load((CONFIGS / "exo_2dof.yaml").read_text())
    with pytest.raises(ConfigError, match="was not read"):
        ModelConfig.from_dict(d, source="mem")


def test_saved_elsewhere_the_urdf_path_still_names_the_file(arm, tmp_path):
    cfg = load_config(arm)
    out = tmp_path / "elsewhere" / "deeper" / "saved.yaml"
    out.parent.mkdir(parents=True)
    save_config(cfg, out)
    again = load_config(out)
    assert again.model.urdf == "../../exo_2dof_arm.urdf"
    np.testing.assert_array_equal(again.model.M, cfg.model.M)
    save_config(cfg, tmp_path / "beside.yaml")
    assert load_config(tmp_path / "beside.yaml").model.urdf == "exo_2dof_arm.urdf"


@pytest.mark.parametrize("old,new,message", [
    # Pinocchio's parser dropped these <inertial> elements (the forearm then had no mass) with only
    # a console message, or took the value as given
    ('<mass value="0.8"/>', '<mass value="nan"/>',
     r"""link 'exo_forearm': <mass value="nan">: allowed a finite number >= 0 \[kg\]"""),
    ('<mass value="0.8"/>', '<mass value="0.8kg"/>', r"""<mass value="0.8kg">: allowed a finite number >= 0"""),
    ('<mass value="0.8"/>', '<mass value="-0.5"/>', r"""link 'exo_forearm': <mass value="-0.5">: allowed"""),
    ('ixx="0.00435"', 'ixx="-1"', r"link 'exo_forearm': <inertia> ixx=-1 .* is not a physical inertia"),
    ('ixx="0.00435"', 'ixx="inf"', r"""<inertia ixx="inf">: allowed a finite number \[kg m\^2\]"""),
    ('ixx="0.00435" ', '', r"link 'exo_forearm': <inertia> has no ixx="),
    ('<origin xyz="0 0 -0.12"/>', '<origin xyz="0 0"/>', r"""<origin xyz="0 0">: allowed 3 finite numbers \[m\]"""),
    # joints: Pinocchio refused these, after several lines on the console
    ('<origin xyz="0 0 -0.3255"/>', '<origin xyz="0 0 nan"/>', r"""joint 'elbow': <origin xyz="0 0 nan">"""),
    ('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>', r"""joint 'shoulder': <axis xyz="0 0 0">: allowed 3 finite numbers, not all 0"""),
    ('lower="0" upper="2.2689"', 'lower="3" upper="2.2689"', r"joint 'elbow': <limit lower=\"3\" upper=\"2.2689\">: allowed lower <= upper"),
    ('effort="20"', 'effort="-20"', r"""joint 'elbow': <limit effort="-20">: allowed a finite number >= 0"""),
])
def test_a_urdf_number_that_is_not_one_is_named(arm, old, new, message):
    urdf = arm.parent / "exo_2dof_arm.urdf"
    text = urdf.read_text()
    assert old in text
    urdf.write_text(text.replace(old, new, 1))
    with pytest.raises(InputError, match=message):
        load_config(arm)


def test_a_working_range_per_joint_in_the_yaml_is_refused_naming_where_it_goes(arm):
    # the list was refused as "must be a finite number within ±1e+09"
    d = yaml.safe_load(arm.read_text())
    d["calibration"] = {"q_min_deg": [10, 20], "q_max_deg": [80, 100]}
    arm.write_text(yaml.safe_dump(d, sort_keys=False))
    with pytest.raises(InputError, match=r"calibration.q_min_deg: must be one angle in -360..360 deg for every joint, "
                                         r"got \[10, 20\] \(one range per joint: .*URDF <limit lower upper>\)"):
        load_config(arm)
