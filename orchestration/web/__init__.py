"""`m2d2m serve`: a web page and an HTTP API over the registered models (docs/serving.md)."""
