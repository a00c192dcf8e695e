"""The dexmon application: session loop, prediction, alerts, run file, replay, CLI."""
