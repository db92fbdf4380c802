"""Device drivers: each speaks its device's real protocol through an injected transport."""
