"""SIL harness: scenarios, node launch, lockstep/real-time clocking, recording, metrics, plots."""
