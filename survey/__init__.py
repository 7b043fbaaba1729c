"""The application: CLI, file formats, project store, exports."""
