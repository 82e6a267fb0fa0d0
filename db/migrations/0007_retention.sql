-- 0007: retention (cvre-admin retention, db/maint.c): the collision log's
-- old entries are removed a time bucket at a time, in short transactions
-- beside a running server. Finding a bucket's groups and a group's user
-- entries must not scan the whole table in each of them, hence two indexes.
-- Each costs the log writer one more b-tree insert per new group or user
-- entry, not per row.

CREATE INDEX collision_groups_by_bucket ON collision_groups(bucket);
CREATE INDEX collision_users_by_group ON collision_users(g);
