"""On-the-fly campaigns: planned in :mod:`gonio.plan.fly` (:mod:`gonio.fly.plans`: the plans of an
``order=fly`` grid), journaled as campaigns of kind ``fly`` (:func:`gonio.campaign.create_campaign`), run
by the engine one sweep per unit (:mod:`gonio.fly.units`): rendered by the simulated gantry
(:mod:`gonio.sim.fly`), or swept on a configured gantry's axes (:mod:`gonio.fly.hardware`)."""

from gonio.fly.plans import fly_plan_of, fly_plans

__all__ = ["fly_plan_of", "fly_plans"]
