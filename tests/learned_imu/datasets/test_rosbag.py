"""ROS bag reader on bags the tests write with ``rosbags`` (ROS 1, ROS 2 sqlite3, ROS 2 MCAP), filled with 10 s
of the real EuRoC V1_02 IMU and ground truth, read back and compared with the EuRoC reader."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from airimu_core.errors import DataError, InputError
from airimu_core.rotations import matrix_to_quat_wxyz
from learned_imu.datasets import ReadChecks
from learned_imu.datasets.euroc import read_euroc
from learned_imu.datasets.rosbag import read_rosbag
from learned_imu.evaluation.evaluate import evaluate

SAMPLES = 2000  # 10 s at 200 Hz


@pytest.fixture(scope="module")
def euroc(shared_data):
    seq = read_euroc(shared_data / "euroc" / "V1_02_medium", imu_file="mav0/imu0/data_partial_first40s.csv")
    return {
        "ns": np.rint(seq.t[:SAMPLES] * 1e9).astype(np.int64),
        "gyro": seq.gyro[:SAMPLES],
        "acc": seq.acc[:SAMPLES],
        "pos": seq.gt.pos[:SAMPLES],
        "rot": seq.gt.rot[:SAMPLES],
        "vel": seq.gt.vel[:SAMPLES],
    }


def _messages(ts, data, gt_type: str, ros1: bool):
    """(topic, msgtype, ns, message) for the IMU, a second IMU topic, and ground truth of ``gt_type``."""
    types = ts.types
    vec3, point, quat = (
        types["geometry_msgs/msg/Vector3"],
        types["geometry_msgs/msg/Point"],
        types["geometry_msgs/msg/Quaternion"],
    )
    pose_t, time_t = types["geometry_msgs/msg/Pose"], types["builtin_interfaces/msg/Time"]

    def header(ns, k):
        stamp = time_t(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
        extra = {"seq": k} if ros1 else {}
        return types["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id="imu")

    q_wxyz = matrix_to_quat_wxyz(data["rot"])
    vel_body = np.einsum("nji,nj->ni", data["rot"], data["vel"])  # Odometry twist is in the child (IMU) frame
    zeros9, zeros36 = np.zeros(9), np.zeros(36)
    for k, ns in enumerate(data["ns"]):
        for topic, scale in (("/imu0", 1.0), ("/zz_imu", 0.5)):
            msg = types["sensor_msgs/msg/Imu"](
                header=header(ns, k),
                orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=zeros9,
                angular_velocity=vec3(*data["gyro"][k]),
                angular_velocity_covariance=zeros9,
                linear_acceleration=vec3(*(scale * data["acc"][k])),
                linear_acceleration_covariance=zeros9,
            )
            yield topic, "sensor_msgs/msg/Imu", int(ns), msg
        w, x, y, z = q_wxyz[k]
        pose = pose_t(position=point(*data["pos"][k]), orientation=quat(x=x, y=y, z=z, w=w))
        if gt_type == "nav_msgs/msg/Odometry":
            twist = types["geometry_msgs/msg/Twist"](linear=vec3(*vel_body[k]), angular=vec3(0.0, 0.0, 0.0))
            gt = types[gt_type](
                header=header(ns, k),
                child_frame_id="imu",
                pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=zeros36),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=zeros36),
            )
        else:
            gt = types[gt_type](header=header(ns, k), pose=pose)
        yield "/gt", gt_type, int(ns) + 1000, gt


def _write_ros1(path, data, gt_type):
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(path) as writer:
        conns = {}
        for topic, msgtype, ns, msg in _messages(ts, data, gt_type, ros1=True):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], ns, ts.serialize_ros1(msg, msgtype))
    return path


def _write_ros2(path, data, gt_type, storage):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(path, version=9, storage_plugin=storage) as writer:
        conns = {}
        for topic, msgtype, ns, msg in _messages(ts, data, gt_type, ros1=False):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], ns, ts.serialize_cdr(msg, msgtype))
    return path


@pytest.fixture(scope="module")
def bags(euroc, tmp_path_factory):
    root = tmp_path_factory.mktemp("bags")
    return {
        "ros1_odometry": _write_ros1(root / "odom.bag", euroc, "nav_msgs/msg/Odometry"),
        "ros2_sqlite_pose": _write_ros2(
            root / "pose_db3", euroc, "geometry_msgs/msg/PoseStamped", StoragePlugin.SQLITE3
        ),
        "ros2_mcap_odometry": _write_ros2(root / "odom_mcap", euroc, "nav_msgs/msg/Odometry", StoragePlugin.MCAP),
    }


@pytest.mark.parametrize("kind", ["ros1_odometry", "ros2_sqlite_pose", "ros2_mcap_odometry"])
def test_bag_round_trip_matches_the_euroc_reader(bags, euroc, kind):
    seq = read_rosbag(bags[kind], gt_topic="/gt")
    assert len(seq) == SAMPLES and seq.gt.valid.all()
    np.testing.assert_allclose(seq.t, euroc["ns"] * 1e-9, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(seq.gyro, euroc["gyro"])  # the default topic is /imu0, first in name order
    np.testing.assert_array_equal(seq.acc, euroc["acc"])
    np.testing.assert_allclose(seq.gt.pos, euroc["pos"], atol=1e-9)
    np.testing.assert_allclose(seq.gt.rot, euroc["rot"], atol=1e-9)
    vel_err = np.linalg.norm(seq.gt.vel - euroc["vel"], axis=1)
    if kind.endswith("odometry"):  # twist rotated from the child frame back to the world frame
        assert vel_err.max() < 1e-9
    else:  # PoseStamped has no velocity: differentiated positions, 3.2 mm/s rms on V1_02 (test_euroc)
        assert np.sqrt((vel_err**2).mean()) < 0.005


def test_bare_mcap_file_and_bag_receive_time(bags, euroc, caplog):
    mcap = next(bags["ros2_mcap_odometry"].glob("*.mcap"))
    with caplog.at_level(logging.WARNING):
        seq = read_rosbag(mcap, stamp="bag", checks=ReadChecks(check_frame=False))
    assert len(seq) == SAMPLES and seq.gt is None
    np.testing.assert_array_equal(seq.gyro, euroc["gyro"])
    # read without ground truth from a bag that has a pose topic: the warning names it and the option
    assert "read without ground truth, though the bag has pose topics ['/gt'] (pass gt_topic=...)" in caplog.text
    with pytest.raises(InputError, match="evaluation needs ground truth.*gt_topic"):
        evaluate(seq, 1.0)


def test_topic_choice_and_errors(bags, euroc):
    bag = bags["ros1_odometry"]
    other = read_rosbag(bag, imu_topic="/zz_imu", checks=ReadChecks(check_units=False))
    np.testing.assert_array_equal(other.acc, 0.5 * euroc["acc"])
    with pytest.raises(DataError, match="has type sensor_msgs/msg/Imu") as err:
        read_rosbag(bag, gt_topic="/zz_imu")
    assert err.value.field == "gt_topic"
    with pytest.raises(DataError, match="'/imu9' not in the bag"):
        read_rosbag(bag, imu_topic="/imu9")


def test_not_a_bag(tmp_path):
    path = tmp_path / "broken.bag"
    path.write_bytes(b"#ROSBAG V2.0\n garbage")
    with pytest.raises(DataError, match="cannot read") as err:
        read_rosbag(path)
    assert err.value.field == "bag"


def test_unset_header_stamps_suggest_bag_time(euroc, tmp_path):
    data = {**euroc, "ns": np.zeros(50, dtype=np.int64)}
    data = {k: v[:50] for k, v in data.items()}
    bag = _write_ros1(tmp_path / "zero.bag", data, "nav_msgs/msg/Odometry")
    with pytest.raises(DataError, match="pass stamp='bag'"):
        read_rosbag(bag)


def test_a_topic_without_messages_names_its_option(euroc, tmp_path):
    """A declared ground-truth topic that holds no message (a recording stopped early, a filtered bag)."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    data = {k: v[:300] for k, v in euroc.items()}
    path = tmp_path / "no_gt.bag"
    with Writer1(path) as writer:
        conns = {"/gt": writer.add_connection("/gt", "nav_msgs/msg/Odometry", typestore=ts)}
        for topic, msgtype, ns, msg in _messages(ts, data, "nav_msgs/msg/Odometry", ros1=True):
            if topic == "/gt":
                continue
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(conns[topic], ns, ts.serialize_ros1(msg, msgtype))
    assert len(read_rosbag(path, checks=ReadChecks(check_units=False))) == 300  # the IMU alone reads
    with pytest.raises(DataError, match="topic '/gt' has no messages") as err:
        read_rosbag(path, gt_topic="/gt")
    assert err.value.field == "gt_topic"
