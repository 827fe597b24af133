"""Key presets of ``[arms.keys]`` read from real TOML files: wrenchd's own layout,
zenoh-bridge-ros2dds's mapping, rmw_zenoh's key expressions; explicit keys keep working."""

from pathlib import Path

import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.settings import load_settings

JS_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
WRENCH_HASH = "RIHS01_8dc3deaf06b2ab281f9f9a742a8961c328ca7cec16e3fd6586d3a5c83fa78f77"


def settings_from(tmp_path: Path, text: str):
    path = tmp_path / "wrenchd.toml"
    path.write_text(text)
    return load_settings(path)


def keys_of(settings, index: int = 0) -> dict[str, str]:
    arm = settings.arms[index]
    return arm.keys.resolve(settings.prefix, arm.name, settings.ros.domain_id)


def test_default_is_wrenchds_layout(tmp_path):
    s = settings_from(tmp_path, 'robot = "external"\n[[arms]]\nname = "PSM2"\n')
    assert keys_of(s) == {"measured_js": "dvrk/PSM2/measured_js",
                          "wrench": "dvrk/PSM2/wrenchd/measured_cf",
                          "events": "dvrk/PSM2/wrenchd/events",
                          "status": "dvrk/PSM2/wrenchd/status",
                          "alive": "dvrk/PSM2/wrenchd/alive", "setup": "dvrk/PSM2/setup"}
    assert s.arms[0].encoding == "json"


def test_ros2dds_shorthand_drops_the_prefix_and_means_cdr(tmp_path):
    s = settings_from(tmp_path, 'robot = "external"\n[[arms]]\nname = "PSM1"\n'
                                'keys = "ros2dds"\n')
    keys = keys_of(s)
    assert (keys["measured_js"], keys["wrench"]) == ("PSM1/measured_js",
                                                     "PSM1/wrenchd/measured_cf")
    assert keys["events"] == "dvrk/PSM1/wrenchd/events"      # wrenchd's own keys stay
    assert s.arms[0].encoding == "cdr"


def test_rmw_zenoh_preset_in_a_table_with_a_domain(tmp_path):
    s = settings_from(tmp_path, 'robot = "external"\n[ros]\ndomain_id = 42\n[[arms]]\n'
                                'name = "PSM3"\n[arms.keys]\npreset = "rmw_zenoh"\n')
    keys = keys_of(s)
    assert keys["measured_js"] == (
        f"42/PSM3/measured_js/sensor_msgs::msg::dds_::JointState_/{JS_HASH}")
    assert keys["wrench"] == (
        f"42/PSM3/wrenchd/measured_cf/geometry_msgs::msg::dds_::WrenchStamped_/{WRENCH_HASH}")
    assert s.arms[0].encoding == "cdr" and s.ros.node == "wrenchd"


def test_rmw_zenoh_topic_names_can_be_given(tmp_path):
    s = settings_from(tmp_path, 'robot = "external"\n[[arms]]\nname = "PSM1"\n[arms.keys]\n'
                                'preset = "rmw_zenoh"\nmeasured_js = "/dvrk/{arm}/measured_js"\n')
    assert keys_of(s)["measured_js"].startswith("0/dvrk/PSM1/measured_js/sensor_msgs::")
    assert s.arms[0].keys.topics(s.prefix, "PSM1")["wrench"] == "/PSM1/wrenchd/measured_cf"


def test_explicit_keys_still_work(tmp_path):
    s = settings_from(tmp_path, 'robot = "external"\nprefix = "or2"\n[[arms]]\nname = "PSM1"\n'
                                '[arms.keys]\nmeasured_js = "lab/{arm}/js"\n'
                                'wrench = "{prefix}/{arm}/force"\n')
    keys = keys_of(s)
    assert (keys["measured_js"], keys["wrench"], keys["status"]) == (
        "lab/PSM1/js", "or2/PSM1/force", "or2/PSM1/wrenchd/status")


@pytest.mark.parametrize("arm_toml, complaint", [
    ('keys = "ros2dds"\nencoding = "json"', "carries ROS 2 CDR"),
    ('keys = "dds"', "preset"),
    ('[arms.keys]\npreset = "rmw_zenoh"\nwrench = "PSM1/force"', "topic name"),
    ('[arms.keys]\nmeasured_js = "dvrk/*/measured_js"', "plain zenoh key"),
])
def test_bad_keys_are_refused(tmp_path, arm_toml, complaint):
    with pytest.raises(ConfigError, match=complaint):
        settings_from(tmp_path, f'robot = "external"\n[[arms]]\nname = "PSM1"\n{arm_toml}\n')


@pytest.mark.parametrize("ros_toml, complaint", [
    ("domain_id = 300", "domain_id"), ('node = "my-node"', "node name"),
    ('namespace = "lab"', "namespace")])
def test_bad_ros_settings_are_refused(tmp_path, ros_toml, complaint):
    with pytest.raises(ConfigError, match=complaint):
        settings_from(tmp_path, f'robot = "external"\n[ros]\n{ros_toml}\n')


def test_the_simulated_robot_needs_wrenchds_keys(tmp_path):
    with pytest.raises(ConfigError, match="external"):
        settings_from(tmp_path, '[[arms]]\nname = "PSM1"\nkeys = "rmw_zenoh"\n')
