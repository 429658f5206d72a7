"""Flight data in: files, logs, channel maps, resampling, segmentation, data quality."""
