"""The planner process beside the loop: motion and excitation plans, feasibility, controller builds."""
