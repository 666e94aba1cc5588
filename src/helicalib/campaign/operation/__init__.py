"""Year-round operation: the re-check rules, the checks of accepted heliostats, drift evidence,
and the crew's requests, each acting on the campaign state through a narrow interface."""
