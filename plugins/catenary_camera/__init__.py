"""Live line-scan cameras (GigE Vision through Aravis; optional extra ``camera``)."""
