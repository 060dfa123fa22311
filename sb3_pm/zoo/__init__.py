"""rl-zoo style configuration: YAML -> keyword arguments, name -> class registries, schedules."""
