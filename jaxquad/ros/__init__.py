"""ROS 1 / ROS 2 bags in and out: robot logs from recordings, estimation results for RViz and Foxglove."""

from jaxquad.ros.convert import convert, convert_bag
from jaxquad.ros.topics import Topics, load_topics

__all__ = ["Topics", "convert", "convert_bag", "load_topics"]
