"""ROS 2 visibility over rmw_zenoh: CDR encoding, message types with their RIHS01 hashes, and the
rmw_zenoh key expressions, attachment and liveliness tokens (docs/ros2.md)."""
