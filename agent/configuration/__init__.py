"""Robot YAML and procedure files -> typed, validated configuration."""
