"""Signal processing of recordings: Allan deviation and noise-model fit (``allan``), static-interval detection
(``detect``), segment means (``segments``, Liu 2021 eqs. 5 and 21-26 observations) and the covariance of segment
means under slow noise (``noisecov``)."""
