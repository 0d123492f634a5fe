"""Map updaters (plug-ins): ``orgb`` (colour OctoMap) and ``multiclass-bayes`` (EVSMaP)."""
