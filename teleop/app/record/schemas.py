"""The record's schemas: the standard ROS 2 message definitions its CDR channels use (the
``ros2msg`` text a ROS 2 bag stores: the message, then each type it names after a line of 80
``=`` and ``MSG: package/Type``), and the JSON Schemas of its JSON channels.

Only the definitions are here; :mod:`teleop.app.record.cdr` lays the bytes out.
"""

from __future__ import annotations

import json

_SEP = "=" * 80 + "\n"

_DEFS = {
    "builtin_interfaces/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "geometry_msgs/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/Pose": "Point position\nQuaternion orientation\n",
    "geometry_msgs/Twist": "Vector3 linear\nVector3 angular\n",
    "geometry_msgs/Wrench": "Vector3 force\nVector3 torque\n",
    "geometry_msgs/Transform": "Vector3 translation\nQuaternion rotation\n",
    "geometry_msgs/PoseStamped": "std_msgs/Header header\nPose pose\n",
    "geometry_msgs/TwistStamped": "std_msgs/Header header\nTwist twist\n",
    "geometry_msgs/WrenchStamped": "std_msgs/Header header\nWrench wrench\n",
    "geometry_msgs/TransformStamped": "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
    "sensor_msgs/JointState": ("std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
                               "float64[] effort\n"),
    "tf2_msgs/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
}

#: the types each type names, in the order a bag lists them
_DEPS = {
    "std_msgs/Header": ("builtin_interfaces/Time",),
    "geometry_msgs/Pose": ("geometry_msgs/Point", "geometry_msgs/Quaternion"),
    "geometry_msgs/Twist": ("geometry_msgs/Vector3",),
    "geometry_msgs/Wrench": ("geometry_msgs/Vector3",),
    "geometry_msgs/Transform": ("geometry_msgs/Vector3", "geometry_msgs/Quaternion"),
    "geometry_msgs/PoseStamped": ("std_msgs/Header", "geometry_msgs/Pose"),
    "geometry_msgs/TwistStamped": ("std_msgs/Header", "geometry_msgs/Twist"),
    "geometry_msgs/WrenchStamped": ("std_msgs/Header", "geometry_msgs/Wrench"),
    "geometry_msgs/TransformStamped": ("std_msgs/Header", "geometry_msgs/Transform"),
    "sensor_msgs/JointState": ("std_msgs/Header",),
    "tf2_msgs/TFMessage": ("geometry_msgs/TransformStamped",),
}

POSE = "geometry_msgs/msg/PoseStamped"
TWIST = "geometry_msgs/msg/TwistStamped"
WRENCH = "geometry_msgs/msg/WrenchStamped"
JOINTS = "sensor_msgs/msg/JointState"
TF = "tf2_msgs/msg/TFMessage"
ROS2 = (POSE, TWIST, WRENCH, JOINTS, TF)


def _closure(name: str, out: list[str]) -> None:
    for dep in _DEPS.get(name, ()):
        _closure(dep, out)
        if dep not in out:
            out.append(dep)


def msgdef(datatype: str) -> str:
    """The ros2msg text of ``datatype`` ("pkg/msg/Type"): its definition, then every type it
    names (depth first, each once)."""
    short = datatype.replace("/msg/", "/")
    deps: list[str] = []
    _closure(short, deps)
    text = _DEFS[short]
    for d in deps:
        text += _SEP + f"MSG: {d}\n" + _DEFS[d]
    return text


def _num(desc: str) -> dict:
    return {"type": "number", "description": desc}


def _vec(n: int, desc: str) -> dict:
    return {"type": "array", "items": {"type": "number"}, "minItems": n, "maxItems": n, "description": desc}


def _obj(title: str, props: dict, desc: str = "") -> dict:
    out = {"type": "object", "title": title, "properties": props}
    if desc:
        out["description"] = desc
    return out


_COMMON = {
    "tick": {"type": "integer", "description": "the tick's index i"},
    "t_s": _num("the run's simulated time of the tick, i * dt (s); the message's log time"),
    "wall_time_s": _num("the wall clock (Unix time, s) when the tick's hooks ran, on this host"),
    "status": {"type": "string", "description": "the side's status after the tick"},
    "heartbeat_lost": {"type": "boolean", "description": "the side's heartbeat says its peer is lost"},
    "tick_us": _num("the side's CPU time for the tick, hooks excluded (us)"),
}

MASTER_STATE = _obj("teleop.MasterTick", {
    **_COMMON,
    "gain": _num("the slave's force as rendered: 1, or ramping after a lost link"),
    "peer_lost": {"type": "boolean", "description": "the newest reply says the slave hears nothing"},
    "command_errors": {"type": "integer", "description": "ticks whose command could not be made (running count)"},
    "hand_force_N": _num("|hand wrench force| (N)"),
    "felt_force_N": _num("|felt wrench force| (N)"),
    "guard": {"type": ["object", "null"], "description": "the passivity guard's master port (null: unguarded)",
              "properties": {"W_J": _vec(6, "observer energy per axis (J)"),
                             "E_diss_J": _vec(6, "dissipated energy per axis, cumulative (J)"),
                             "alpha": _vec(6, "damping applied per axis")}},
}, "The master side's tick: everything not in a ROS 2 message")

SLAVE_STATE = _obj("teleop.SlaveTick", {
    **_COMMON,
    "last_command_seq": {"type": "integer", "description": "the newest command taken (its seq)"},
    "ticks_without_command": {"type": "integer", "description": "ticks with no new command (running count)"},
    "commands_skipped": {"type": "integer", "description": "commands never followed (running count)"},
    "tracking_error_m": _num("|p - p_target| of the slave tool (m, patient frame)"),
    "tracking_error_rad": _num("angle between the slave tool's orientation and its target's (rad)"),
    "contact_force_N": _num("|tissue force| at the blade tip (N)"),
    "guard": {"type": ["object", "null"], "description": "the passivity guard's slave port (null: unguarded)",
              "properties": {"W_J": _vec(6, "observer energy per axis (J)"),
                             "E_diss_J": _vec(6, "dissipated energy per axis, cumulative (J)"),
                             "drift_M": _vec(6, "pose offset (m, rad in M)")}},
}, "The slave side's tick: everything not in a ROS 2 message")

CAN_FRAME = _obj("teleop.CanFrame", {
    "t_s": _num("the frame's end on the modelled wire, on the run's clock (s); the log time"),
    "bus_t_s": _num("the same on the bus model's own clock (s)"),
    "id": {"type": "integer", "description": "arbitration id"},
    "rx": {"type": "boolean", "description": "received by the host (false: the host sent it)"},
    "fd": {"type": "boolean"}, "error": {"type": "boolean", "description": "an error frame"},
    "dlc": {"type": "integer"}, "data": {"type": "string", "description": "the payload, hex"},
}, "One CAN frame on the cobot's bus, as the host sees the wire")

LINK_EVENT = _obj("teleop.LinkEvent", {
    "t_s": _num("the run's simulated time of the event (s); the log time"),
    "wall_time_s": _num("the wall clock (Unix time, s) when it was recorded"),
    "side": {"type": "string", "description": "the end that saw it: master or slave"},
    "kind": {"type": "string", "description": "sent, delivered, lost, refused, ..."},
    "seq": {"type": ["integer", "null"]},
    "detail": {"type": ["object", "string", "null"]},
}, "An event of the link between the sides")


LINK_TICK = _obj("teleop.LinkTick", {
    "tick": {"type": "integer", "description": "the side's tick"},
    "t_s": _num("the tick's simulated time (s); the log time"),
    "seq": {"type": "integer", "description": "the message the link handed the tick (its seq; -1 none)"},
    "hello": {"type": "boolean", "description": "that message was the start-up's hello"},
    "clock_s": _num("the link's clock as the tick read it (s; time.monotonic: CLOCK_MONOTONIC on this host)"),
    "heard_s": _num("when the side last heard its peer, as its heartbeat read it (s, same clock; null: never)"),
    "sent_s": _num("when the tick's own message was sent (s, same clock)"),
    "chain_s": _vec(6, "the master: T1..T6 of the reply applied (command sent, received, applied; reply sent, "
                       "received, applied); the slave: T1..T3 of the command applied (s; null: none)"),
}, "A side's link at one tick: the delivery schedule a replay follows, and the messages' time stamps")

OPERATOR_KEYS = _obj("teleop.OperatorKeys", {
    "tick": {"type": "integer", "description": "the tick whose hand read the keys"},
    "t_s": _num("the run's simulated time of that tick (s); the log time"),
    "text": {"type": "string", "description": "the characters read from the terminal at that tick, as typed"},
}, "What the person at the keyboard typed, read by the tick it acted on (teleop replay --check feeds it again)")


def json_schema(schema: dict) -> bytes:
    return json.dumps(schema, separators=(",", ":")).encode()
