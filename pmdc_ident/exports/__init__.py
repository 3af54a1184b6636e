"""The identified motor in other tools' formats: MuJoCo MJCF, URDF, ros2_control."""
