"""Thin rclpy nodes: the only layer that imports rclpy and message packages."""

from pmdc_ident._blas import limit_blas_threads

# Node processes import numpy right after this package: one BLAS thread each (see _blas).
limit_blas_threads()
