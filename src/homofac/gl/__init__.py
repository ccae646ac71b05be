"""homofac.gl."""
