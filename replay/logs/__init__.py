"""Logs in and out (docs/formats.md): the damage-tolerant MCAP scanner (``mcap_scan``), the reader and
its frame stream (``reader``, ``stream``, yielding :class:`~replay.logs.frame.Frame`), the ROS 2 codecs
(``ros2_msgs``), PCD and PLY files (``pcd``, ``ply``), the writers (``writer``, ``mcap_write``), the
layout's names (``layout``) and damage as typed records (``damage``)."""
