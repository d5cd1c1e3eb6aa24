"""Robots: articulated bodies in reduced coordinates."""
