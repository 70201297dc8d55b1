"""Distance-based region subdivision (Rishe et al.): LOD rings around the nadir, a horizon
cut-off and a navigation-speed factor."""
