"""The service and the CLI: indicators in, decisions, events and alarms out."""
