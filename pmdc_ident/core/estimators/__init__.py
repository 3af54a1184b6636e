"""Identification estimators: classical chain, equation error, frequency response, output error."""
