"""
What crosses the wire and the disk, without rclpy.

What crosses the wire and the disk, without rclpy: the topic contract and its CDR bytes, MCAP
recording and reading, re-simulation of a log.
"""
