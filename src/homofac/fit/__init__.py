"""homofac.fit."""
