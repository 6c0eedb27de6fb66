"""Global inspection planner (the paper's section "Wind Turbine Inspection Path Planner").

Three steps, each in its own module: :mod:`.clustering` groups blade triangles into surfaces by
geometry, :mod:`.ordering` finds the exact shortest surface tour (Held-Karp over subsets instead of
the paper's brute force), :mod:`.path` joins the surfaces' centre lines with collision-free
transitions (:mod:`.clearance`) and resamples them; :mod:`.plan` chooses the rotor positions (or
takes the paper's one turn), runs the phases around the turns and holds the result, :mod:`.plot`
draws it.
"""
from .clustering import Surface, cluster_surfaces, describe_surface
from .config import PlannerConfig
from .ordering import HeldKarp, TourSolution, solve_tour, tour_cost
from .plan import CSV_HEADER, InspectionPlan, RotorPosition, TourStop, plan_inspection

__all__ = ["CSV_HEADER", "HeldKarp", "InspectionPlan", "PlannerConfig", "RotorPosition", "Surface", "TourSolution",
           "TourStop", "cluster_surfaces", "describe_surface", "plan_inspection", "solve_tour", "tour_cost"]
