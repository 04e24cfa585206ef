"""Identity from sigma, expressions from alpha, expression events (seed §3.6, §4.5; issue 7)."""
