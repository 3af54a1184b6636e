"""pmdc_ident: identify brushed permanent-magnet DC motor parameters.

The ROS-free layers (core, io, backends, cli) never import rclpy or message
packages; only ``pmdc_ident.nodes`` does.
"""

__version__ = "0.1.0"
