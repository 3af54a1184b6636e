"""The nodes' processes without ROS: bring-up and launch descriptions, DDS domain
locks, scheduling priorities, the identification worker, the nodes' parameter tables
and settings, the ``/diagnostics`` naming scheme.

Nothing here imports rclpy or a message package (``test/test_ros_free_core.py``);
``pmdc_ident.nodes`` (the ``Node`` subclasses, QoS and parameter declaration) and the
demo build on it.
"""

from pmdc_ident._blas import limit_blas_threads

# bringup, the launch files and the identification worker start processes that import
# numpy right after this package: one BLAS thread each (see _blas), as for the nodes.
limit_blas_threads()
