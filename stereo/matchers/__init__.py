"""Matcher backends (see ``staticdepth.stereo.match``)."""
