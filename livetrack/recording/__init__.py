"""Recordings: a directory of PNG frames, their metadata and optional truth poses (format v1).

See docs/recording-format.md for the format, ``RecordingWriter`` to write one, ``Recording.open`` to read one.
"""

from livetrack.recording._format import FrameRecord, RecordingError
from livetrack.recording.reader import Recording
from livetrack.recording.writer import RecordingWriter

__all__ = ["FrameRecord", "Recording", "RecordingError", "RecordingWriter"]
