//! Black-box API tests: the real service on an ephemeral port with a temporary database.

mod approach;
mod bridges;
mod concurrency;
mod demonstrations;
mod errors;
mod figures;
mod grasps;
mod health;
mod helpers;
mod jobs;
mod limits;
mod mappings;
mod models;
mod obstacles;
mod openapi;
mod paths;
mod plans;
mod plans_ui;
mod process;
mod quickstart;
mod retarget;
mod robots;
mod storage;
