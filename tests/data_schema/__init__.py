"""Tests of madp.data_schema."""
