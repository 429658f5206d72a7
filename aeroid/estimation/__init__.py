"""Time-domain estimators: output error, filter error, equation-error regression,
data compatibility, state filtering; their records and shared kernels."""
