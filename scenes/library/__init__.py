"""Built-in scenes, generated deterministically."""
