//! Bridge workers: WebSocket protocol, dispatcher, persistent execution queue, simulated robot.
