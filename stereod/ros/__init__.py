"""ROS 2 and Foxglove: MCAP export, MCAP during a run, rmw_zenoh topics and the Foxglove server."""
