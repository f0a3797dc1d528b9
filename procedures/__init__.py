"""Scripted pose sequences, stored as YAML data beside this file."""
