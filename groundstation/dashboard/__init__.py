"""The live telemetry dashboard: a pure model of what each vehicle sent (model) and its web server (server)."""
