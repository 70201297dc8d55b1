"""The terrain-collapse tool (Wang's thesis): fold away the land between two picked points;
its displacement runs in the vertex shader, picks report true coordinates."""
