"""Sources of stereo frames and LiDAR scans: hardware adapters, MCAP replay, the synthetic rig.

A source is an iterable of events (`StereoFrame`, `LidarScan`, and for replay and the rig
`Calibration` / `GroundTruth`), a context manager, and stops on `close()` from any thread."""
