using System.Collections.Generic;
using System.Linq;

namespace Vista.Client
{
    /// <summary>What a reviewer can say about a defect.</summary>
    public static class Verdicts
    {
        /// <summary>The defect is real.</summary>
        public const string Confirmed = "confirmed";
        /// <summary>The defect is not real.</summary>
        public const string Rejected = "rejected";
        /// <summary>The defect is real but of another type (give the new type).</summary>
        public const string Reclassified = "reclassified";
        /// <summary>The reviewer cannot tell.</summary>
        public const string Uncertain = "uncertain";

        /// <summary>All verdicts, in the server's order.</summary>
        public static readonly string[] All = { Confirmed, Rejected, Reclassified, Uncertain };
    }

    /// <summary>The kinds of defect the supervisor reports.</summary>
    public static class DefectTypes
    {
        /// <summary>All defect types, in the server's order.</summary>
        public static readonly string[] All = { "gap", "step", "parallelism", "mismatch", "scratch", "dent", "bump", "color", "deviation" };
    }

    /// <summary>The answer to a sign-in: a bearer token and when it expires.</summary>
    public sealed class TokenInfo
    {
        /// <summary>The bearer token.</summary>
        public string AccessToken;
        /// <summary>When the token expires (ISO 8601), or null if it does not.</summary>
        public string ExpiresAt;

        /// <summary>Reads the API's <c>{access_token, expires_at}</c>.</summary>
        public static TokenInfo FromJson(IDictionary<string, object> json)
        {
            return new TokenInfo
            {
                AccessToken = json.GetRequiredString("access_token"),
                ExpiresAt = json.GetString("expires_at"),
            };
        }
    }

    /// <summary>Who a token belongs to (<c>GET /api/v1/me</c>).</summary>
    public sealed class UserInfo
    {
        /// <summary>The user's id.</summary>
        public long Id;
        /// <summary>The user's name.</summary>
        public string Username;
        /// <summary>admin, inspector, viewer or device.</summary>
        public string Role;
        /// <summary>session, cli or device.</summary>
        public string TokenKind;

        /// <summary>Reads the API's <c>{id, username, role, token_kind}</c>.</summary>
        public static UserInfo FromJson(IDictionary<string, object> json)
        {
            return new UserInfo
            {
                Id = json.GetInt64("id"),
                Username = json.GetRequiredString("username"),
                Role = json.GetString("role"),
                TokenKind = json.GetString("token_kind"),
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "id", Id }, { "username", Username }, { "role", Role }, { "token_kind", TokenKind },
            };
        }
    }

    /// <summary>A finding of an inspection, as the sync sends it. Times are ISO 8601 text.</summary>
    public sealed class Defect
    {
        /// <summary>The defect's id.</summary>
        public long Id;
        /// <summary>The measuring run that found it, or null when reported by hand.</summary>
        public long? RunId;
        /// <summary>gap, step, parallelism, mismatch, scratch, dent, bump, color or deviation.</summary>
        public string Type;
        /// <summary>open, resolved, … (the server's workflow state).</summary>
        public string Status;
        /// <summary>info, minor, major, critical.</summary>
        public string Severity;
        /// <summary>out (beyond its limit by 2σ or more), within, or uncertain (within 2σ of
        /// its limit: measure again; <c>Measurements["advice"]</c> says how).</summary>
        public string ToleranceState;
        /// <summary>The measured value, in <see cref="Unit"/>, if the type has one.</summary>
        public double? Value;
        /// <summary>mm, or delta_e for a colour patch.</summary>
        public string Unit;
        /// <summary>The tolerance the value is judged against, in <see cref="Unit"/>, if any.</summary>
        public double? Tolerance;
        /// <summary>Where it is: (x, y, z) in the base frame, mm, +Z up.</summary>
        public double[] LocationMm;
        /// <summary>The surface normal there (unit vector, base frame).</summary>
        public double[] Normal;
        /// <summary>How large it is, mm.</summary>
        public double ExtentMm;
        /// <summary>How sure the measurement is, 0–1.</summary>
        public double Confidence;
        /// <summary>job or manual.</summary>
        public string Source;
        /// <summary>The measurement's details (type-specific).</summary>
        public Dictionary<string, object> Measurements;
        /// <summary>When it was found.</summary>
        public string CreatedAt;
        /// <summary>Null while current; "superseded" (a later measurement found it again:
        /// <see cref="SupersededById"/>) or "not found again". An ended finding is history:
        /// <see cref="SyncClient"/> keeps it out of <see cref="SyncClient.Defects"/>.</summary>
        public string Ended;
        /// <summary>The later measurement's finding that continues this one, or null.</summary>
        public long? SupersededById;
        /// <summary>The earlier measurement's finding this one continues, or null.</summary>
        public long? SupersedesId;
        /// <summary>The first finding of its line: every measurement of one physical defect shares it.</summary>
        public long? LineageId;
        /// <summary>The run that ended it, or null.</summary>
        public long? EndedRunId;
        /// <summary>What people noted about it, oldest first (empty: none).</summary>
        public List<DefectNote> Notes = new List<DefectNote>();

        /// <summary>Reads a defect of the sync.</summary>
        public static Defect FromJson(IDictionary<string, object> json)
        {
            return new Defect
            {
                Id = json.GetInt64("id"),
                RunId = json.GetNullableInt64("run_id"),
                Type = json.GetRequiredString("type"),
                Status = json.GetRequiredString("status"),
                Severity = json.GetString("severity"),
                ToleranceState = json.GetString("tolerance_state")
                    ?? (json.GetString("severity") == "info" ? "within" : "out"),
                Value = json.GetNullableDouble("value"),
                Unit = json.GetString("unit") ?? "mm",
                Tolerance = json.GetNullableDouble("tolerance"),
                LocationMm = json.GetDoubles("location_mm"),
                Normal = json.GetDoubles("normal"),
                ExtentMm = json.GetNullableDouble("extent_mm") ?? 0,
                Confidence = json.GetNullableDouble("confidence") ?? 0,
                Source = json.GetString("source"),
                Measurements = json.GetObject("measurements") ?? new Dictionary<string, object>(),
                CreatedAt = json.GetString("created_at"),
                Ended = json.GetString("ended"),
                SupersededById = json.GetNullableInt64("superseded_by_id"),
                SupersedesId = json.GetNullableInt64("supersedes_id"),
                LineageId = json.GetNullableInt64("lineage_id"),
                EndedRunId = json.GetNullableInt64("ended_run_id"),
                Notes = json.GetObjects("notes").Select(DefectNote.FromJson).ToList(),
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "id", Id }, { "run_id", RunId }, { "type", Type }, { "status", Status },
                { "severity", Severity }, { "tolerance_state", ToleranceState },
                { "value", Value }, { "unit", Unit }, { "tolerance", Tolerance },
                { "location_mm", LocationMm }, { "normal", Normal }, { "extent_mm", ExtentMm },
                { "confidence", Confidence }, { "source", Source }, { "measurements", Measurements },
                { "created_at", CreatedAt }, { "ended", Ended }, { "superseded_by_id", SupersededById },
                { "supersedes_id", SupersedesId }, { "lineage_id", LineageId }, { "ended_run_id", EndedRunId },
                { "notes", Notes.Select(n => (object)n.ToJson()).ToList() },
            };
        }
    }

    /// <summary>A note someone added to a finding (a finding reported by hand, or any other).</summary>
    public sealed class DefectNote
    {
        /// <summary>Who wrote it (null: a user since removed).</summary>
        public string Username;
        /// <summary>What they wrote.</summary>
        public string Text;
        /// <summary>When, ISO 8601.</summary>
        public string At;

        /// <summary>Reads one note of a defect.</summary>
        public static DefectNote FromJson(IDictionary<string, object> json)
        {
            return new DefectNote { Username = json.GetString("username"), Text = json.GetString("text") ?? "", At = json.GetString("at") };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object> { { "username", Username }, { "text", Text }, { "at", At } };
        }
    }

    /// <summary>One user's current judgment of one defect.</summary>
    public sealed class Judgment
    {
        /// <summary>The defect judged.</summary>
        public long DefectId;
        /// <summary>Who judged.</summary>
        public long UserId;
        /// <summary>Their name.</summary>
        public string Username;
        /// <summary>One of <see cref="Verdicts"/>.</summary>
        public string Verdict;
        /// <summary>The type it should be, when the verdict is reclassified; otherwise null.</summary>
        public string NewType;
        /// <summary>Free text.</summary>
        public string Comment;
        /// <summary>How often the server changed it (0: not on the server yet).</summary>
        public int Revision;
        /// <summary>When the server last changed it.</summary>
        public string UpdatedAt;
        /// <summary>When the user made it, by the device's clock.</summary>
        public string ClientTime;
        /// <summary>The earlier run whose finding it was judged on (carried over when the
        /// finding was measured again), or null: judged on this finding.</summary>
        public long? JudgedOnRunId;

        /// <summary>Reads a judgment of the sync.</summary>
        public static Judgment FromJson(IDictionary<string, object> json)
        {
            return new Judgment
            {
                DefectId = json.GetInt64("defect_id"),
                UserId = json.GetInt64("user_id"),
                Username = json.GetString("username"),
                Verdict = json.GetRequiredString("verdict"),
                NewType = json.GetString("new_type"),
                Comment = json.GetString("comment") ?? "",
                Revision = checked((int)json.GetInt64("revision")),
                UpdatedAt = json.GetString("updated_at"),
                ClientTime = json.GetString("client_time"),
                JudgedOnRunId = json.GetNullableInt64("judged_on_run_id"),
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "defect_id", DefectId }, { "user_id", UserId }, { "username", Username },
                { "verdict", Verdict }, { "new_type", NewType }, { "comment", Comment },
                { "revision", Revision }, { "updated_at", UpdatedAt }, { "client_time", ClientTime },
                { "judged_on_run_id", JudgedOnRunId },
            };
        }
    }

    /// <summary>What the reviewers of one defect think, from each one's current judgment.</summary>
    public sealed class Consensus
    {
        /// <summary>Share of votes the majority needs for the defect not to need review.</summary>
        public const double AgreementNeeded = 2.0 / 3.0;

        /// <summary>The defect.</summary>
        public long DefectId;
        /// <summary>Votes per verdict (every verdict present, zero or more).</summary>
        public Dictionary<string, int> Counts;
        /// <summary>Number of judgments.</summary>
        public int Total;
        /// <summary>The verdict with strictly the most votes, or null.</summary>
        public string Majority;
        /// <summary>Share of judgments that agree with the most-voted verdict.</summary>
        public double Agreement;
        /// <summary>No strict majority, the majority is uncertain, or too little agreement.</summary>
        public bool NeedsReview;
        /// <summary>Votes per new type among the reclassified verdicts.</summary>
        public Dictionary<string, int> ReclassifiedAs;

        /// <summary>Reads a consensus of the sync.</summary>
        public static Consensus FromJson(IDictionary<string, object> json)
        {
            return new Consensus
            {
                DefectId = json.GetInt64("defect_id"),
                Counts = json.GetCounts("counts"),
                Total = checked((int)json.GetInt64("total")),
                Majority = json.GetString("majority"),
                Agreement = json.GetNullableDouble("agreement") ?? 0,
                NeedsReview = json.GetBoolean("needs_review", false),
                ReclassifiedAs = json.GetCounts("reclassified_as"),
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "defect_id", DefectId }, { "counts", Counts }, { "total", Total },
                { "majority", Majority }, { "agreement", Agreement }, { "needs_review", NeedsReview },
                { "reclassified_as", ReclassifiedAs },
            };
        }

        /// <summary>The votes of a verdict (0 when none).</summary>
        public int CountOf(string verdict)
        {
            int count;
            return Counts != null && Counts.TryGetValue(verdict, out count) ? count : 0;
        }

        /// <summary>The consensus of these judgments of one defect, by the server's rules (used
        /// for judgments not pushed yet; the server's own consensus replaces it on sync).</summary>
        public static Consensus Tally(long defectId, IEnumerable<Judgment> judgments)
        {
            var counts = Verdicts.All.ToDictionary(v => v, v => 0);
            var retyped = new Dictionary<string, int>();
            foreach (Judgment judgment in judgments)
            {
                Increment(counts, judgment.Verdict);
                if (judgment.Verdict == Verdicts.Reclassified && !string.IsNullOrEmpty(judgment.NewType))
                {
                    Increment(retyped, judgment.NewType);
                }
            }
            int total = counts.Values.Sum();
            var ranked = counts.OrderByDescending(pair => pair.Value).ToList();
            string majority = total > 0 && ranked[0].Value > ranked[1].Value ? ranked[0].Key : null;
            double agreement = total > 0 ? (double)ranked[0].Value / total : 0.0;
            return new Consensus
            {
                DefectId = defectId,
                Counts = counts,
                Total = total,
                Majority = majority,
                Agreement = agreement,
                NeedsReview = total > 0
                    && (majority == null || majority == Verdicts.Uncertain || agreement < AgreementNeeded),
                ReclassifiedAs = retyped,
            };
        }

        static void Increment(Dictionary<string, int> counts, string key)
        {
            int before;
            counts.TryGetValue(key, out before);
            counts[key] = before + 1;
        }
    }

    /// <summary>A printed image marker at a known pose in the base frame.</summary>
    public sealed class ImageMarker
    {
        /// <summary>The marker's name; the scene's anchor node is <c>marker-&lt;name&gt;</c>.</summary>
        public string Name;
        /// <summary>cargo or cabin.</summary>
        public string Area;
        /// <summary>The marker's frame (x right, y up the image, z out of it) in the base frame, mm.</summary>
        public Matrix4 BaseFromMarker;
        /// <summary>Printed edge length, mm.</summary>
        public double SizeMm;
        /// <summary>The target's name in the AR library.</summary>
        public string Image;

        /// <summary>Reads a marker of an inspection.</summary>
        public static ImageMarker FromJson(IDictionary<string, object> json)
        {
            var rows = new List<double[]>();
            foreach (object row in json.GetArray("base_T_marker"))
            {
                rows.Add(JsonFields.AsDoubles(row, "base_T_marker"));
            }
            return new ImageMarker
            {
                Name = json.GetRequiredString("name"),
                Area = json.GetString("area"),
                BaseFromMarker = Matrix4.FromRows(rows),
                SizeMm = json.GetDouble("size_mm"),
                Image = json.GetString("image") ?? "",
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "name", Name }, { "area", Area }, { "base_T_marker", BaseFromMarker.ToRows() },
                { "size_mm", SizeMm }, { "image", Image },
            };
        }
    }

    /// <summary>The parts of an inspection a headset needs.</summary>
    public sealed class Inspection
    {
        /// <summary>The inspection's id.</summary>
        public long Id;
        /// <summary>Its title.</summary>
        public string Title;
        /// <summary>cargo, cabin or component.</summary>
        public string Area;
        /// <summary>planned, scanning, processing, review or closed.</summary>
        public string Status;
        /// <summary>Its image markers (for alignment).</summary>
        public List<ImageMarker> Markers;

        /// <summary>Reads an inspection (other fields are ignored).</summary>
        public static Inspection FromJson(IDictionary<string, object> json)
        {
            return new Inspection
            {
                Id = json.GetInt64("id"),
                Title = json.GetString("title"),
                Area = json.GetString("area"),
                Status = json.GetString("status"),
                Markers = json.GetObjects("markers").Select(ImageMarker.FromJson).ToList(),
            };
        }

        /// <summary>The same fields, as the API writes them.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "id", Id }, { "title", Title }, { "area", Area }, { "status", Status },
                { "markers", Markers.Select(m => m.ToJson()).ToList() },
            };
        }
    }

    /// <summary>A page of inspections.</summary>
    public sealed class InspectionPage
    {
        /// <summary>The inspections of this page.</summary>
        public List<Inspection> Items;
        /// <summary>Pass as <c>cursor</c> for the next page; null on the last.</summary>
        public string NextCursor;

        /// <summary>Reads <c>{items, next_cursor}</c>.</summary>
        public static InspectionPage FromJson(IDictionary<string, object> json)
        {
            return new InspectionPage
            {
                Items = json.GetObjects("items").Select(Inspection.FromJson).ToList(),
                NextCursor = json.GetString("next_cursor"),
            };
        }
    }

    /// <summary>A finished job with a 3D scene (a trajectory, depth clouds, a track), as a sync
    /// page lists it.</summary>
    public sealed class JobSceneRef
    {
        /// <summary>The job.</summary>
        public long JobId;
        /// <summary>Its run.</summary>
        public long RunId;
        /// <summary>Its kind (<c>odometry.run</c>, <c>depth.predict</c>, <c>tracking.track</c>, …).</summary>
        public string Kind;
        /// <summary>Its step's name in the run.</summary>
        public string Step;
        /// <summary>When it finished (RFC 3339), or null.</summary>
        public string FinishedAt;

        /// <summary>Reads <c>{job_id, run_id, kind, step, finished_at, url}</c>.</summary>
        public static JobSceneRef FromJson(IDictionary<string, object> json)
        {
            return new JobSceneRef
            {
                JobId = json.GetInt64("job_id"),
                RunId = json.GetInt64("run_id"),
                Kind = json.GetRequiredString("kind"),
                Step = json.GetString("step"),
                FinishedAt = json.GetString("finished_at"),
            };
        }
    }

    /// <summary>A succeeded job that could not do all it was asked (a measurement's unmeasured
    /// seams), as a sync page lists it: the inspection is not done while one is listed.</summary>
    public sealed class JobWarning
    {
        /// <summary>The job.</summary>
        public long JobId;
        /// <summary>Its run.</summary>
        public long RunId;
        /// <summary>Its kind (<c>defects.measure</c>, …).</summary>
        public string Kind;
        /// <summary>Its step's name in the run.</summary>
        public string Step;
        /// <summary>What it could not do, and why.</summary>
        public string Warning;
        /// <summary>How many seams a measurement left unmeasured (null: not a measurement's).</summary>
        public long? UnmeasuredSeams;

        /// <summary>Reads <c>{job_id, run_id, kind, step, warning, unmeasured_seams}</c>.</summary>
        public static JobWarning FromJson(IDictionary<string, object> json)
        {
            return new JobWarning
            {
                JobId = json.GetInt64("job_id"),
                RunId = json.GetInt64("run_id"),
                Kind = json.GetRequiredString("kind"),
                Step = json.GetString("step"),
                Warning = json.GetRequiredString("warning"),
                UnmeasuredSeams = json.GetNullableInt64("unmeasured_seams"),
            };
        }

        /// <summary>The fields <see cref="FromJson"/> reads.</summary>
        public Dictionary<string, object> ToJson()
        {
            return new Dictionary<string, object>
            {
                { "job_id", JobId }, { "run_id", RunId }, { "kind", Kind }, { "step", Step },
                { "warning", Warning }, { "unmeasured_seams", UnmeasuredSeams },
            };
        }
    }

    /// <summary>One page of <c>GET /api/v1/sync</c>: what changed after a cursor.</summary>
    public sealed class SyncPage
    {
        /// <summary>The inspection, when the page starts a full sync or it changed; else null.</summary>
        public Inspection Inspection;
        /// <summary>Defects created or changed (their state now).</summary>
        public List<Defect> Defects;
        /// <summary>Judgments created or changed.</summary>
        public List<Judgment> Judgments;
        /// <summary>The consensus of every defect whose judgments are in this page.</summary>
        public List<Consensus> Consensus;
        /// <summary>The ETag of the inspection's scene.glb now.</summary>
        public string SceneEtag;
        /// <summary>The inspection's finished jobs with a 3D scene of their own, newest first.</summary>
        public List<JobSceneRef> JobScenes;
        /// <summary>The inspection's succeeded jobs with a warning (unmeasured seams), newest
        /// first.</summary>
        public List<JobWarning> Warnings;
        /// <summary>Pass as <c>since</c> next time.</summary>
        public string NextCursor;
        /// <summary>Another page waits: call again at once with <see cref="NextCursor"/>.</summary>
        public bool More;

        /// <summary>Reads a sync page.</summary>
        public static SyncPage FromJson(IDictionary<string, object> json)
        {
            Dictionary<string, object> inspection = json.GetObject("inspection");
            return new SyncPage
            {
                Inspection = inspection == null ? null : Inspection.FromJson(inspection),
                Defects = json.GetObjects("defects").Select(Defect.FromJson).ToList(),
                Judgments = json.GetObjects("judgments").Select(Judgment.FromJson).ToList(),
                Consensus = json.GetObjects("consensus").Select(Vista.Client.Consensus.FromJson).ToList(),
                SceneEtag = json.GetString("scene_etag"),
                JobScenes = json.GetObjects("job_scenes").Select(JobSceneRef.FromJson).ToList(),
                Warnings = json.GetObjects("warnings").Select(JobWarning.FromJson).ToList(),
                NextCursor = json.GetRequiredString("next_cursor"),
                More = json.GetBoolean("more", false),
            };
        }
    }

    /// <summary>A judgment made on the device, waiting in the outbox to be pushed.</summary>
    public sealed class OfflineJudgment
    {
        /// <summary>Made here (a GUID); a retry sends the same one and gets the first answer.</summary>
        public string ClientId;
        /// <summary>The defect judged.</summary>
        public long DefectId;
        /// <summary>The inspection the defect was synced from: the server refuses the item
        /// when the defect is not in it.</summary>
        public long? InspectionId;
        /// <summary>One of <see cref="Verdicts"/>.</summary>
        public string Verdict;
        /// <summary>The new type, exactly when the verdict is reclassified.</summary>
        public string NewType;
        /// <summary>Free text (at most 4000 characters).</summary>
        public string Comment;
        /// <summary>When the user judged, UTC, ISO 8601 with a trailing Z.</summary>
        public string ClientTime;

        /// <summary>Reads an outbox item (the push body's item shape).</summary>
        public static OfflineJudgment FromJson(IDictionary<string, object> json)
        {
            return new OfflineJudgment
            {
                ClientId = json.GetRequiredString("client_id"),
                DefectId = json.GetInt64("defect_id"),
                InspectionId = json.GetNullableInt64("inspection_id"),
                Verdict = json.GetRequiredString("verdict"),
                NewType = json.GetString("new_type"),
                Comment = json.GetString("comment") ?? "",
                ClientTime = json.GetRequiredString("client_time"),
            };
        }

        /// <summary>The item as <c>POST /api/v1/sync/judgments</c> takes it.</summary>
        public Dictionary<string, object> ToJson()
        {
            var json = new Dictionary<string, object>
            {
                { "client_id", ClientId }, { "defect_id", DefectId }, { "verdict", Verdict },
                { "new_type", NewType }, { "comment", Comment }, { "client_time", ClientTime },
            };
            if (InspectionId.HasValue)
                json["inspection_id"] = InspectionId.Value;
            return json;
        }

        /// <summary>How the judgment looks locally before the server has it (revision 0).</summary>
        public Judgment ToLocalJudgment(UserInfo user)
        {
            return new Judgment
            {
                DefectId = DefectId,
                UserId = user.Id,
                Username = user.Username,
                Verdict = Verdict,
                NewType = NewType,
                Comment = Comment,
                Revision = 0,
                UpdatedAt = ClientTime,
                ClientTime = ClientTime,
            };
        }
    }

    /// <summary>A judgment the server refused: kept, with the server's reason, until the
    /// user has read it and clears it (<see cref="SyncClient.ClearRefused"/>); never sent again.</summary>
    public sealed class RefusedJudgment
    {
        /// <summary>The judgment as it was queued.</summary>
        public OfflineJudgment Item;
        /// <summary>Why the server refused it, in its words.</summary>
        public string Reason;

        /// <summary>Reads a refused item (the outbox item's shape with a <c>reason</c>).</summary>
        public static RefusedJudgment FromJson(IDictionary<string, object> json)
        {
            return new RefusedJudgment { Item = OfflineJudgment.FromJson(json), Reason = json.GetRequiredString("reason") };
        }

        /// <summary>The outbox item's shape with a <c>reason</c>.</summary>
        public Dictionary<string, object> ToJson()
        {
            Dictionary<string, object> json = Item.ToJson();
            json["reason"] = Reason;
            return json;
        }
    }

    /// <summary>The server's answer to one pushed item.</summary>
    public sealed class ItemResult
    {
        /// <summary>The applied status: your judgment now.</summary>
        public const string Applied = "applied";
        /// <summary>The same as your judgment already was.</summary>
        public const string Unchanged = "unchanged";
        /// <summary>You judged this defect later (by client time) elsewhere; that one stays.</summary>
        public const string Stale = "stale";
        /// <summary>Refused; <see cref="Detail"/> says why.</summary>
        public const string Rejected = "rejected";

        /// <summary>The item's client id.</summary>
        public string ClientId;
        /// <summary>The defect.</summary>
        public long DefectId;
        /// <summary>applied, unchanged, stale or rejected.</summary>
        public string Status;
        /// <summary>This client id was sent before: this is the first answer again.</summary>
        public bool Replayed;
        /// <summary>Why (for stale and rejected), or null.</summary>
        public string Detail;
        /// <summary>Your judgment of the defect on the server now, or null.</summary>
        public Judgment Judgment;
        /// <summary>The finding the judgment landed on when the one it was sent for had been
        /// measured again since (its successor; <see cref="Detail"/> says so), or null.</summary>
        public long? LandedOn;

        /// <summary>Reads one result of a push.</summary>
        public static ItemResult FromJson(IDictionary<string, object> json)
        {
            Dictionary<string, object> judgment = json.GetObject("judgment");
            return new ItemResult
            {
                ClientId = json.GetRequiredString("client_id"),
                DefectId = json.GetInt64("defect_id"),
                Status = json.GetRequiredString("status"),
                Replayed = json.GetBoolean("replayed", false),
                Detail = json.GetString("detail"),
                Judgment = judgment == null ? null : Judgment.FromJson(judgment),
                LandedOn = json.GetNullableInt64("landed_on"),
            };
        }
    }

    /// <summary>The answer to a push: one result per item, in order, and the new consensus of
    /// every defect a judgment was applied to.</summary>
    public sealed class PushResult
    {
        /// <summary>One per item sent.</summary>
        public List<ItemResult> Results;
        /// <summary>The consensus of the defects whose judgments changed.</summary>
        public List<Consensus> Consensus;

        /// <summary>Reads <c>{results, consensus}</c>.</summary>
        public static PushResult FromJson(IDictionary<string, object> json)
        {
            return new PushResult
            {
                Results = json.GetObjects("results").Select(ItemResult.FromJson).ToList(),
                Consensus = json.GetObjects("consensus").Select(Vista.Client.Consensus.FromJson).ToList(),
            };
        }
    }

    /// <summary>A conditional download of scene.glb.</summary>
    public sealed class SceneDownload
    {
        /// <summary>The copy sent in If-None-Match is current (HTTP 304); no bytes.</summary>
        public bool NotModified;
        /// <summary>The GLB file (null when not modified).</summary>
        public byte[] Bytes;
        /// <summary>The scene's ETag, quotes included, as the server sent it.</summary>
        public string ETag;
    }
}
