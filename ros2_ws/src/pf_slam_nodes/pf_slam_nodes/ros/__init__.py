"""ROS glue shared by the nodes: topic names, QoS profiles, message <-> ndarray conversions.

Everything ROS-specific lives here or in ``nodes/``; ``core/`` never imports rclpy.
"""
