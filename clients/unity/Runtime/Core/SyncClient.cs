using System;
using System.Collections.Generic;
using System.Globalization;
using System.IO;
using System.Linq;
using System.Text;
using System.Threading.Tasks;

namespace Vista.Client
{
    /// <summary>
    /// The headset's local copy of one inspection (defects, everyone's judgments, consensus,
    /// the scene's ETag and the sync cursor) and its outbox of judgments made offline.
    /// <para>
    /// Judgments are optimistic: <see cref="Judge"/> queues an item and the copy shows it at
    /// once; <see cref="PushAsync"/> sends the outbox when online. An item leaves the outbox
    /// only once the server has answered it, so a push cut off by the network is simply sent
    /// again (the server answers a retried <c>client_id</c> as the first time); an item the
    /// server refuses moves to <see cref="Refused"/> with the reason and stays there until the
    /// user clears it, so no verdict is lost without the user having seen why. Keep one
    /// instance per inspection and call it from one thread (Unity's main thread): the awaits
    /// here resume on the caller's context.
    /// </para>
    /// </summary>
    public sealed class SyncClient
    {
        /// <summary>Most items the server takes in one push.</summary>
        public const int MaxBatch = 1000;

        const int StateVersion = 2;

        readonly VistaApi api;
        readonly Dictionary<long, Defect> defects = new Dictionary<long, Defect>();
        readonly Dictionary<long, Defect> ended = new Dictionary<long, Defect>();
        readonly Dictionary<long, Dictionary<long, Judgment>> judgments = new Dictionary<long, Dictionary<long, Judgment>>();
        readonly Dictionary<long, Consensus> consensus = new Dictionary<long, Consensus>();
        readonly List<OfflineJudgment> outbox = new List<OfflineJudgment>();
        readonly List<RefusedJudgment> refused = new List<RefusedJudgment>();
        DateTime lastClientTime = DateTime.MinValue;
        int batchSize = MaxBatch;
        Task<int> syncing;
        Task<List<ItemResult>> pushing;

        /// <summary>A copy of inspection <paramref name="inspectionId"/>, empty until
        /// <see cref="SyncAsync"/> or <see cref="LoadState"/>.</summary>
        public SyncClient(VistaApi api, long inspectionId)
        {
            if (api == null)
            {
                throw new ArgumentNullException("api");
            }
            this.api = api;
            InspectionId = inspectionId;
        }

        /// <summary>The device's clock, UTC (a judgment's <c>client_time</c>).</summary>
        public Func<DateTime> Clock { get; set; } = () => DateTime.UtcNow;

        /// <summary>The inspection this is a copy of.</summary>
        public long InspectionId { get; private set; }

        /// <summary>The signed-in user (from <see cref="VistaApi.GetMeAsync"/>); needed to judge.
        /// Saved with the state, so a restarted headset can judge offline.</summary>
        public UserInfo User { get; set; }

        /// <summary>The inspection (null before the first sync).</summary>
        public Inspection Inspection { get; private set; }

        /// <summary>Where the next sync starts (null: from the beginning).</summary>
        public string Cursor { get; private set; }

        /// <summary>The scene's ETag as of the last sync.</summary>
        public string SceneEtag { get; private set; }

        /// <summary>The ETag of the scene last downloaded by <see cref="DownloadSceneAsync"/>.</summary>
        public string DownloadedSceneEtag { get; private set; }

        /// <summary>The inspection's succeeded jobs with a warning as of the last sync (a
        /// measurement that left seams unmeasured, and why), newest first: show them before
        /// anyone signs. Saved with the state, so an offline headset still shows them.</summary>
        public List<JobWarning> Warnings { get; private set; } = new List<JobWarning>();

        /// <summary>The server's scene differs from the one downloaded: fetch it again.</summary>
        public bool SceneChanged
        {
            get { return SceneEtag != null && SceneEtag != DownloadedSceneEtag; }
        }

        /// <summary>Defects or log entries per sync page (null: the server's default).</summary>
        public int? PageLimit { get; set; }

        /// <summary>Items per push request, 1 to <see cref="MaxBatch"/> (the default); smaller
        /// batches lose less work to a flaky link.</summary>
        public int BatchSize
        {
            get { return batchSize; }
            set
            {
                if (value < 1 || value > MaxBatch)
                {
                    throw new ArgumentOutOfRangeException("value", "a batch holds 1 to " + MaxBatch + " items");
                }
                batchSize = value;
            }
        }

        /// <summary>The current defects, by id: each physical defect once.</summary>
        public IReadOnlyDictionary<long, Defect> Defects
        {
            get { return defects; }
        }

        /// <summary>Findings a later measurement ended (superseded, or not found again), by
        /// id: history, not shown. A verdict queued for one still goes out; the server lands
        /// it on the successor (<see cref="ItemResult.LandedOn"/>) or refuses it with the reason.</summary>
        public IReadOnlyDictionary<long, Defect> Ended
        {
            get { return ended; }
        }

        /// <summary>The current finding that continues <paramref name="defectId"/> (itself
        /// while current); null when a later measurement did not find it again, or the copy
        /// does not know it.</summary>
        public long? SuccessorOf(long defectId)
        {
            var seen = new HashSet<long>();
            long id = defectId;
            Defect gone;
            while (ended.TryGetValue(id, out gone) && seen.Add(id))
            {
                if (gone.SupersededById == null)
                {
                    return null;
                }
                id = gone.SupersededById.Value;
            }
            return defects.ContainsKey(id) ? id : (long?)null;
        }

        /// <summary>Judgments made here that the server has not answered yet, oldest first.</summary>
        public IReadOnlyList<OfflineJudgment> Outbox
        {
            get { return outbox; }
        }

        /// <summary>Judgments the server refused, oldest first, each with its reason; kept
        /// (and saved with the state) until <see cref="ClearRefused"/>.</summary>
        public IReadOnlyList<RefusedJudgment> Refused
        {
            get { return refused; }
        }

        /// <summary>Forgets the refused judgments once the user has read them; returns how many.</summary>
        public int ClearRefused()
        {
            int count = refused.Count;
            refused.Clear();
            return count;
        }

        /// <summary>A user's judgment of a defect as shown here: the user's newest judgment
        /// in the outbox if any, else the server's; null when there is none.</summary>
        public Judgment JudgmentOf(long defectId, long userId)
        {
            if (User != null && userId == User.Id)
            {
                OfflineJudgment pending = outbox.LastOrDefault(item => IsFor(item, defectId));
                if (pending != null)
                {
                    Judgment local = pending.ToLocalJudgment(User);
                    Judgment stored = ServerJudgment(defectId, userId);
                    local.Revision = stored == null ? 0 : stored.Revision;
                    return local;
                }
            }
            return ServerJudgment(defectId, userId);
        }

        /// <summary>Every user's judgment of a defect as shown here, by user id.</summary>
        public List<Judgment> JudgmentsOf(long defectId)
        {
            var users = new SortedSet<long>();
            Dictionary<long, Judgment> byUser;
            if (judgments.TryGetValue(defectId, out byUser))
            {
                users.UnionWith(byUser.Keys);
            }
            if (User != null && outbox.Any(item => IsFor(item, defectId)))
            {
                users.Add(User.Id);
            }
            return users.Select(user => JudgmentOf(defectId, user)).ToList();
        }

        /// <summary>The consensus of a defect as shown here: the server's, or a local tally
        /// while judgments of it wait in the outbox; null when nobody judged it.</summary>
        public Consensus ConsensusOf(long defectId)
        {
            if (outbox.Any(item => IsFor(item, defectId)))
            {
                return Consensus.Tally(defectId, JudgmentsOf(defectId));
            }
            Consensus known;
            return consensus.TryGetValue(defectId, out known) ? known : null;
        }

        /// <summary>Pulls everything that changed since <see cref="Cursor"/>, page after page
        /// while the server says more waits; returns the number of pages. Each page is applied
        /// and its cursor kept before the next is asked for, so an interrupted sync resumes.
        /// A sync already running is joined, not started twice. A deleted inspection throws
        /// <see cref="VistaApiException"/> with status 410: drop the local copy.</summary>
        public Task<int> SyncAsync()
        {
            if (syncing == null || syncing.IsCompleted)
            {
                syncing = RunSyncAsync();
            }
            return syncing;
        }

        async Task<int> RunSyncAsync()
        {
            int pages = 0;
            SyncPage page;
            do
            {
                page = await api.GetSyncPageAsync(InspectionId, Cursor, PageLimit);
                Apply(page);
                pages++;
            }
            while (page.More);
            return pages;
        }

        void Apply(SyncPage page)
        {
            if (page.Inspection != null)
            {
                Inspection = page.Inspection;
            }
            foreach (Defect defect in page.Defects)
            {
                Keep(defect);
            }
            foreach (Judgment judgment in page.Judgments)
            {
                StoreJudgment(judgment);
            }
            foreach (Consensus item in page.Consensus)
            {
                consensus[item.DefectId] = item;
            }
            SceneEtag = page.SceneEtag;
            Warnings = page.Warnings;
            Cursor = page.NextCursor;
        }

        /// <summary>A queued judgment shows on the finding it was made for, or on the one
        /// that has continued it since (the server lands it there).</summary>
        bool IsFor(OfflineJudgment item, long defectId)
        {
            return item.DefectId == defectId || SuccessorOf(item.DefectId) == defectId;
        }

        void Keep(Defect defect)
        {
            if (defect.Ended != null)
            {
                defects.Remove(defect.Id);
                ended[defect.Id] = defect;
            }
            else
            {
                defects[defect.Id] = defect;
            }
        }

        /// <summary>Judges a defect here and now: queues the judgment in the outbox (a new
        /// client id, the device's UTC time) and shows it at once. <paramref name="newType"/>
        /// is given exactly when the verdict is <see cref="Verdicts.Reclassified"/>.</summary>
        public OfflineJudgment Judge(long defectId, string verdict, string newType = null, string comment = "")
        {
            if (User == null)
            {
                throw new InvalidOperationException("Set User (GET /api/v1/me) before judging.");
            }
            if (!defects.ContainsKey(defectId))
            {
                throw new ArgumentException("There is no defect " + defectId + " in the local copy.");
            }
            if (Array.IndexOf(Verdicts.All, verdict) < 0)
            {
                throw new ArgumentException("verdict: one of " + string.Join(", ", Verdicts.All) + ".");
            }
            bool reclassified = verdict == Verdicts.Reclassified;
            if (reclassified != (newType != null) || (reclassified && Array.IndexOf(DefectTypes.All, newType) < 0))
            {
                throw new ArgumentException("newType: one of " + string.Join(", ", DefectTypes.All)
                    + ", given exactly when the verdict is reclassified.");
            }
            if (reclassified && defects[defectId].Type == newType)
            {
                throw new ArgumentException("Defect " + defectId + " already is a " + newType + "; reclassify it as another type.");
            }
            var item = new OfflineJudgment
            {
                ClientId = Guid.NewGuid().ToString(),
                DefectId = defectId,
                InspectionId = InspectionId,
                Verdict = verdict,
                NewType = newType,
                Comment = comment ?? "",
                ClientTime = NextClientTime(),
            };
            outbox.Add(item);
            return item;
        }

        /// <summary>Now, UTC, to the microsecond (what the server keeps), and always later than
        /// the judgment before: two quick judgments of one defect must not tie.</summary>
        string NextClientTime()
        {
            DateTime now = Clock().ToUniversalTime();
            now = new DateTime(now.Ticks - now.Ticks % 10, DateTimeKind.Utc);
            if (now <= lastClientTime)
            {
                now = lastClientTime.AddTicks(10);
            }
            lastClientTime = now;
            return now.ToString("yyyy-MM-dd'T'HH:mm:ss.ffffff'Z'", CultureInfo.InvariantCulture);
        }

        /// <summary>Sends the outbox in batches of <see cref="BatchSize"/> and returns
        /// the server's results. Every answered item leaves the outbox (applied, unchanged,
        /// stale or rejected) and the server's judgment in the answer replaces the local one;
        /// a rejected item moves to <see cref="Refused"/> with the server's reason and the
        /// copy falls back to the server's judgment. When the network fails
        /// the exception propagates and the unanswered items stay for the next push. A push
        /// already running is joined.</summary>
        public Task<List<ItemResult>> PushAsync()
        {
            if (pushing == null || pushing.IsCompleted)
            {
                pushing = RunPushAsync();
            }
            return pushing;
        }

        async Task<List<ItemResult>> RunPushAsync()
        {
            var results = new List<ItemResult>();
            List<OfflineJudgment> pending = outbox.ToList();
            for (int start = 0; start < pending.Count; start += batchSize)
            {
                List<OfflineJudgment> batch = pending.GetRange(start, Math.Min(batchSize, pending.Count - start));
                PushResult answer = await api.PushJudgmentsAsync(batch);
                Apply(answer);
                results.AddRange(answer.Results);
            }
            return results;
        }

        void Apply(PushResult answer)
        {
            foreach (ItemResult result in answer.Results)
            {
                if (result.Status == ItemResult.Rejected)
                {
                    refused.AddRange(outbox.Where(item => item.ClientId == result.ClientId)
                        .Select(item => new RefusedJudgment { Item = item, Reason = result.Detail ?? "refused by the server" }));
                }
                outbox.RemoveAll(item => item.ClientId == result.ClientId);
                if (result.Judgment != null)
                {
                    StoreJudgment(result.Judgment);
                }
            }
            foreach (Consensus item in answer.Consensus)
            {
                consensus[item.DefectId] = item;
            }
        }

        /// <summary>Downloads scene.glb unless the copy held is current. With
        /// <paramref name="haveCopy"/> the ETag of the last download goes in If-None-Match
        /// (answer: not modified while it is current); without, the scene always comes.</summary>
        public async Task<SceneDownload> DownloadSceneAsync(bool haveCopy)
        {
            SceneDownload download = await api.GetSceneAsync(InspectionId, haveCopy ? DownloadedSceneEtag : null);
            if (!download.NotModified)
            {
                DownloadedSceneEtag = download.ETag;
            }
            return download;
        }

        /// <summary>Writes the cursor, the outbox, the refused items, the user and the copy to a JSON file
        /// (written aside, then moved over the old one).</summary>
        public void SaveState(string path)
        {
            var state = new Dictionary<string, object>
            {
                { "version", StateVersion },
                { "inspection_id", InspectionId },
                { "cursor", Cursor },
                { "scene_etag", SceneEtag },
                { "downloaded_scene_etag", DownloadedSceneEtag },
                { "user", User == null ? null : User.ToJson() },
                { "inspection", Inspection == null ? null : Inspection.ToJson() },
                { "defects", defects.Values.Concat(ended.Values).OrderBy(d => d.Id).Select(d => d.ToJson()).ToList() },
                { "judgments", judgments.Values.SelectMany(byUser => byUser.Values).Select(j => j.ToJson()).ToList() },
                { "consensus", consensus.Values.Select(c => c.ToJson()).ToList() },
                { "outbox", outbox.Select(item => item.ToJson()).ToList() },
                { "refused", refused.Select(item => item.ToJson()).ToList() },
                { "warnings", Warnings.Select(item => item.ToJson()).ToList() },
            };
            string temporary = path + ".part";
            File.WriteAllText(temporary, Json.Serialize(state), new UTF8Encoding(false));
            if (File.Exists(path))
            {
                File.Replace(temporary, path, null);
            }
            else
            {
                File.Move(temporary, path);
            }
        }

        /// <summary>Replaces the copy, the outbox and the refused items with those saved in a
        /// file; false (and nothing changed) when the file does not exist. A file of another
        /// inspection or an unknown version throws <see cref="FormatException"/>; a version 1
        /// file (before refused items were kept) loads with none.</summary>
        public bool LoadState(string path)
        {
            if (!File.Exists(path))
            {
                return false;
            }
            Dictionary<string, object> state = Json.ParseObject(File.ReadAllText(path, Encoding.UTF8));
            long version = state.GetInt64("version");
            if (version != StateVersion && version != 1)
            {
                throw new FormatException(path + ": state version " + state.GetInt64("version") + " is not " + StateVersion + ".");
            }
            if (state.GetInt64("inspection_id") != InspectionId)
            {
                throw new FormatException(path + " holds inspection " + state.GetInt64("inspection_id") + ", not " + InspectionId + ".");
            }
            Dictionary<string, object> user = state.GetObject("user");
            Dictionary<string, object> inspection = state.GetObject("inspection");
            defects.Clear();
            ended.Clear();
            judgments.Clear();
            consensus.Clear();
            outbox.Clear();
            refused.Clear();
            Cursor = state.GetString("cursor");
            SceneEtag = state.GetString("scene_etag");
            DownloadedSceneEtag = state.GetString("downloaded_scene_etag");
            User = user == null ? null : UserInfo.FromJson(user);
            Inspection = inspection == null ? null : Inspection.FromJson(inspection);
            foreach (Dictionary<string, object> defect in state.GetObjects("defects"))
            {
                Keep(Defect.FromJson(defect));
            }
            foreach (Dictionary<string, object> judgment in state.GetObjects("judgments"))
            {
                StoreJudgment(Judgment.FromJson(judgment));
            }
            foreach (Dictionary<string, object> item in state.GetObjects("consensus"))
            {
                Consensus tally = Consensus.FromJson(item);
                consensus[tally.DefectId] = tally;
            }
            outbox.AddRange(state.GetObjects("outbox").Select(OfflineJudgment.FromJson));
            refused.AddRange(state.GetObjects("refused").Select(RefusedJudgment.FromJson));
            Warnings = state.GetObjects("warnings").Select(JobWarning.FromJson).ToList();
            return true;
        }

        Judgment ServerJudgment(long defectId, long userId)
        {
            Dictionary<long, Judgment> byUser;
            Judgment judgment;
            return judgments.TryGetValue(defectId, out byUser) && byUser.TryGetValue(userId, out judgment) ? judgment : null;
        }

        void StoreJudgment(Judgment judgment)
        {
            Dictionary<long, Judgment> byUser;
            if (!judgments.TryGetValue(judgment.DefectId, out byUser))
            {
                byUser = new Dictionary<long, Judgment>();
                judgments[judgment.DefectId] = byUser;
            }
            byUser[judgment.UserId] = judgment;
        }
    }
}
