"""End-to-end jobs: photos -> restored scene (restore) and the LOM evaluation protocol."""
