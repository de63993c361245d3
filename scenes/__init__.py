"""Job schema (pydantic), built-in scenes and example jobs."""
