"""On-the-fly campaigns: planned in :mod:`gonio.plan.fly`, journaled one sweep per transaction here
(:mod:`gonio.fly.campaign`); the simulated gantry's readings come from :mod:`gonio.sim.fly`, a configured
gantry's (Dynamixel sweeping axes, through the runner) from :mod:`gonio.fly.hardware`."""

from gonio.fly.campaign import create_fly_campaign, fly_plan_of, run_fly_campaign

__all__ = ["create_fly_campaign", "run_fly_campaign", "fly_plan_of"]
