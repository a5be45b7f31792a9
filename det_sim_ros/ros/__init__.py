"""The ROS 2 layer: the node, markers, fleets and the pytest plugin (imports rclpy)."""
