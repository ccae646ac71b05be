"""homofac.param."""
