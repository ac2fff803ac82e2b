"""Running procedures on a station: runner, procedure context, plan checks, station, safety, acquisition."""
