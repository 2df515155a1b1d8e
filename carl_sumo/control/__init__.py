"""Controllers: the V2V channel, sensors, base car-following models and the classical CACC of
Ploeg et al. Imports ``sim`` and below."""
