"""ROS message types that rosbags does not ship: Livox ``CustomMsg``.

The definitions follow livox_ros_driver (ROS1, package ``livox_ros_driver``) and
livox_ros_driver2 (ROS1/ROS2, package ``livox_ros_driver2``); both use the same fields.
Readers and the simulator's writer register them through :func:`register_livox_types`.
"""

from __future__ import annotations

from typing import Any

LIVOX_PACKAGES = ("livox_ros_driver", "livox_ros_driver2")

CUSTOM_POINT_MSG = """
uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""

CUSTOM_MSG_TEMPLATE = """
std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
{package}/CustomPoint[] points
"""


def livox_custom_msg_types(package: str = "livox_ros_driver") -> dict[str, Any]:
    """Type definitions for ``{package}/msg/CustomMsg`` and ``CustomPoint`` (rosbags format).

    ``offset_time`` is the point's time after ``timebase`` in ns; ``timebase`` is the absolute
    time of the first point in ns.
    """
    from rosbags.typesys import get_types_from_msg

    types: dict[str, Any] = {}
    types.update(get_types_from_msg(CUSTOM_POINT_MSG, f"{package}/msg/CustomPoint"))
    types.update(
        get_types_from_msg(CUSTOM_MSG_TEMPLATE.format(package=package), f"{package}/msg/CustomMsg")
    )
    return types


def register_livox_types(typestore: Any) -> Any:
    """Registers Livox ``CustomMsg``/``CustomPoint`` of both driver packages on ``typestore``."""
    for package in LIVOX_PACKAGES:
        typestore.register(livox_custom_msg_types(package))
    return typestore
