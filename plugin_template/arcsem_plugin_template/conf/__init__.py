"""Hydra configs of this plugin package (arcsem adds them to its search path: entry point ``arcsem.conf``)."""
