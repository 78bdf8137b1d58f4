"""Takes: crash-safe recording of raw servo readings, and playback."""
