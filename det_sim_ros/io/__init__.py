"""
What crosses the wire and the disk, without rclpy.

The topic contract and its CDR bytes, MCAP recording and reading, re-simulation of a log.
"""
