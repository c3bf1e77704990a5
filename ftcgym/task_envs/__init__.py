"""Composite envs that close a loop around a vehicle env: a controller or a detector inside, an action one
level up. Registered as `ftcgym/QuadPlaneAutopilot-v0` (`autopilot`), `ftcgym/RotorLossRecovery-v0`
(`rotor_loss_recovery`) and `ftcgym/AirspeedSource-v0` (`airspeed_source`)."""
