"""Outputs of the live pipeline, each owned by one thread.

``base`` (the Sink protocol and the TrackedFrame record), ``runner`` (bounded drop-oldest hand-off and the thread
owning each sink), ``factory`` (the configured outputs), ``console`` (per-frame lines), ``pose_message`` (the
versioned pose message, docs/pose-stream.md), ``udp`` and ``zmq_pub`` (pose streams), ``rerun_sink`` (viewer),
``recording_sink`` (acquired frames as a v1 recording). Import the module you need: rerun and zmq load lazily.
"""
